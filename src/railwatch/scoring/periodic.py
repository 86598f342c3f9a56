"""The wheel's periodic impulses: a noise level that follows them, by comparison with the same
phase of the neighbouring periods (``docs/nuisance-glr.md``).

A wheel flat or an out-of-round wheel strikes the rail once a revolution: a train of short
impulses at one period in a window (the paper's stage 8). They are not the defect, but one of
them looks like a spike or a short box to the scan, and taking them out by a synchronous
average leaves most of that: a narrow impulse sampled at another sub-sample phase every period
differs from period to period by several noise standard deviations (``docs/nuisance-glr.md``
gives what each way of doing it recovered). What holds from period to period is that its samples
are large. So the residual's noise level at each sample is raised to the robust power at the same
phase of the ``reach`` periods on either side (each taken as the largest square within ±``tol``
samples, for the sub-sample jitter), over the power that noise alone would give there, divided
by ``guard``; where that is below the level, the level stays. A defect does not repeat a period
later and keeps its level; an impulse does.

The period is the window's own: the shortest strong peak of the whitened residual's
autocorrelation (smoothed, so that a narrow pulse on a period between samples does not split it)
between ``min_period`` and ``max_period`` samples, refined by a parabola. Only series whose
autocorrelation there reaches ``correlation`` are followed; elsewhere, and where the
neighbours' power is the noise's, the level does not move.

The periods are in samples: 10-50 at 100 Hz is a wheel revolution at the benchmark's scale. On a
recording kept at 2 kHz a revolution (2.9 m for the physics world's 0.46 m wheel radius,
`railwatch.physics.vehicle`) lasts 100-290 ms at 10-30 m/s, 190-580 samples, and the range
must be set to match.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import maximum_filter1d
from scipy.special import ndtri

F64 = NDArray[np.float64]


def period(w: F64, min_period: int, max_period: int, octave: float = 0.8
           ) -> tuple[F64, F64]:
    """Per series (B, T), the lag in ``[min_period, max_period]`` (and at most T / 2) of the
    largest autocorrelation, to a fraction of a sample; the shortest lag whose autocorrelation
    reaches ``octave`` times the largest, if shorter (a multiple of the period, on a period
    that falls between samples, can align better than the period itself).

    >>> t = np.arange(200)
    >>> x = (np.mod(t, 23.4) < 2).astype(float)[None, :]  # a pulse every 23.4 samples
    >>> bool(abs(period(x, 10, 50)[0][0] - 23.4) < 0.5)
    True
    """
    n_steps = w.shape[1]
    spectrum = np.fft.rfft(w - w.mean(axis=1, keepdims=True), 2 * n_steps, axis=1)
    # of the series smoothed by [1, 2, 1] / 4 (gain cos²(π f)): a pulse a sample wide on a
    # period between samples would split its correlation between two lags
    smooth = np.cos(np.pi * np.fft.rfftfreq(2 * n_steps)) ** 4
    acf = np.fft.irfft(np.abs(spectrum) ** 2 * smooth, 2 * n_steps, axis=1)
    lags = np.arange(min_period, min(max_period, n_steps // 2) + 1)
    rows = np.arange(len(w))
    a = acf[:, lags]
    peaks = np.zeros_like(a, dtype=bool)  # local maxima of the autocorrelation
    peaks[:, 1:-1] = (a[:, 1:-1] >= a[:, :-2]) & (a[:, 1:-1] >= a[:, 2:])
    strong = peaks & (a >= octave * a.max(axis=1, keepdims=True))
    i = np.where(strong.any(axis=1), strong.argmax(axis=1), a.argmax(axis=1))
    left = acf[rows, lags[np.maximum(i - 1, 0)]]
    mid = acf[rows, lags[i]]
    right = acf[rows, lags[np.minimum(i + 1, len(lags) - 1)]]
    curve = left - 2 * mid + right
    step = np.where(curve < 0, 0.5 * (left - right) / np.where(curve < 0, curve, -1.0), 0.0)
    return lags[i] + np.clip(step, -0.5, 0.5), mid / np.maximum(acf[:, 0], 1e-300)


def null_power(tol: int) -> float:
    """The median of the largest of ``2 tol + 1`` squared N(0, 1) samples: what noise alone
    gives at the same phase of another period.

    >>> round(null_power(0), 3)
    0.455
    """
    share = 0.5 ** (1.0 / (2 * tol + 1))  # P(max of 2 tol + 1 squares <= x) = 1/2
    return float(ndtri(0.5 + share / 2) ** 2)


def synchronous_level(w: F64, min_period: int, max_period: int, guard: float,
                      correlation: float = 0.0, reach: int = 3, tol: int = 1) -> F64:
    """Per sample (B, T), the factor (>= 1) by which the whitened residual ``w``'s noise level
    rises at its own :func:`period`: √(median over the ``reach`` periods on either side of the
    largest ``w²`` within ±``tol`` samples, over :func:`null_power`) / ``guard``, where at least
    two such periods lie in the window; 1 elsewhere (module docstring)."""
    n_steps = w.shape[1]
    if n_steps // 2 < min_period:  # not two periods in the window
        return np.ones_like(w)
    per, rho = period(w, min_period, max_period)
    out = np.ones_like(w)
    rows = np.flatnonzero(rho >= correlation)  # only series that repeat are looked at
    if not len(rows):
        return out
    w, per = w[rows], per[rows]
    peak = maximum_filter1d(w * w, 2 * tol + 1, axis=1, mode="nearest")
    ks = np.r_[np.arange(-reach, 0), np.arange(1, reach + 1)]
    pos = np.arange(n_steps)[None, :, None] + np.rint(ks[None, :] * per[:, None])[:, None, :]
    pos = pos.astype(np.int64)  # (B, T, K): the same phase, k periods away
    inside = (pos >= 0) & (pos < n_steps)
    vals = np.take_along_axis(peak, np.clip(pos, 0, n_steps - 1).reshape(len(rows), -1), axis=1)
    vals = np.sort(np.where(inside, vals.reshape(pos.shape), np.inf), axis=2)  # valid first
    count = inside.sum(axis=2)
    lo = np.take_along_axis(vals, np.maximum((count - 1) // 2, 0)[:, :, None], axis=2)[:, :, 0]
    hi = np.take_along_axis(vals, np.minimum(count // 2, len(ks) - 1)[:, :, None], axis=2)[:, :, 0]
    median = np.where(count >= 2, 0.5 * (lo + hi), 0.0)
    out[rows] = np.maximum(1.0, np.sqrt(median / null_power(tol)) / guard)
    return out
