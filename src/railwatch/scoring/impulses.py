"""The wheel's periodic impulses, fitted and taken out of a whitened residual
(``docs/nuisance-glr.md``).

A wheel flat strikes the rail once a revolution: an impulse with a sharp onset that decays within
a few samples, repeating at one period in a window (the paper's stage 8). One such impulse looks
like a spike or a short box to the scan, and a level raised at the same phase of the neighbouring
periods (:mod:`railwatch.scoring.periodic`) hides a defect that falls there as well. Here the
train itself is fitted, per series of the whitened residual ``w``:

    Σ_k a_k g((t − φ − k P) / ω),  g(u) = exp(−u²) for 0 <= u <= 3, else 0,

a one-sided Gaussian of width ``ω`` samples (the benchmark's shape; a flat's impact, a sharp onset
and a decay) at onsets ``φ + k P``, with an amplitude ``a_k >= 0`` of its own per impulse: a flat
strikes harder or softer as the load changes, the last period of a window may hold no impulse,
and a small error in ``φ`` or ``P`` would otherwise leave a spike's worth at every impulse. The
amplitudes are bounded by ``cap`` times the train's median amplitude, so that a defect that falls
on an impulse is not wholly explained by it (a box's share that is: ``tests/scoring``).

The fit, vectorised over the series:

1. the period ``P`` from the autocorrelation (:func:`railwatch.scoring.periodic.period`), and
   only series whose autocorrelation there reaches ``correlation`` are fitted;
2. the onset ``φ`` in ``[0, P)`` on a grid of quarter samples, and the period again within a
   sample of the first: the largest sum of the residual's jumps ``w[n] − w[n − 1]`` at the
   first samples after the onsets (an impulse's onset is its largest jump, whatever its width);
3. the width on a geometric grid ``min_width`` .. ``max_width`` (steps of √2), then ``φ``, ``P``
   and the width refined one at a time on finer grids, each candidate scored by the energy (the
   drop of the residual's sum of squares, in noise variances) that the train explains with one
   common amplitude (overlapping impulses add);
4. the impulses one at a time (overlapping impulses share samples), each with its amplitude
   (``>= 0``, capped from the second sweep on) and a shift of its onset within ±1 sample, for
   :data:`SWEEPS` sweeps: a narrow impulse one sample late leaves a spike of its height, and a
   train whose period drifts (a wheel that speeds up) moves the later onsets.

The train is taken out where it explains more than ``minimum`` noise variances per period of the
window (the search on pure noise finds about 1.4 per period, median, and 2.5 at the 90th
percentile).

What it recovers and what it costs (``docs/notes/2026-12-07-an-impulse-train-model.md``): with
the harmonic nuisance known, taking the fitted train out of the stage-8 residual lifts the spike
and box scan from 0.587 to 0.883 instance ROC-AUC at the true level (the loss page's third
table); inside nuisance-glr, where the harmonic model is fitted to the series with the train in
it, it loses.

Everything is in samples: a wheel revolution at the benchmark's scale is 10-50 samples at
100 Hz and a flat's impulse 1-10 samples wide. On a recording kept at 2 kHz a revolution lasts
190-580 samples (``railwatch.scoring.periodic``) and the ranges must be set to match.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railwatch.scoring.periodic import period

F64 = NDArray[np.float64]

#: An impulse's support, in widths: g(u) = exp(−u²) for 0 <= u <= SUPPORT.
SUPPORT = 3.0
#: Series fitted at once in the grid searches (bounds their (series, grid, T) arrays).
CHUNK = 64
#: Sweeps of the impulse-by-impulse fit (step 4).
SWEEPS = 6


@dataclass(frozen=True)
class Train:
    """The fitted train of every series (B,): onset ``φ`` and period ``P`` (samples), width
    ``ω`` (samples), the energy it explains (noise variances), whether it is taken out, and the
    fit (B, T), zero where it is not."""

    onset: F64
    period: F64
    width: F64
    energy: F64
    kept: NDArray[np.bool_]
    fit: F64


def shape(u: F64, width: F64 | float) -> F64:
    """The impulse ``g(u / width)`` at ``u`` samples after its onset (zero before it and after
    ``SUPPORT`` widths).

    >>> shape(np.array([-1.0, 0.0, 2.0, 7.0]), 2.0).round(3).tolist()
    [0.0, 1.0, 0.368, 0.0]
    """
    v = np.asarray(u, dtype=np.float64) / width
    return np.where((v >= 0) & (v <= SUPPORT), np.exp(-np.minimum(v * v, 50.0)), 0.0)


def impulse_indices(n_steps: int, min_period: float, max_width: float) -> NDArray[np.int64]:
    """The impulse numbers ``k`` whose onset ``φ + k P`` (``0 <= φ < P``, ``P >= min_period``)
    may touch a window of ``n_steps`` samples: from those begun before it whose tail reaches
    into it to the last that begins inside it."""
    before = int(np.ceil(SUPPORT * max_width / min_period)) + 1
    return np.arange(-before, int(np.ceil(n_steps / min_period)) + 1)


def explained(w: F64, onset: F64, per: F64, width: F64) -> F64:
    """The energy (B, G) that trains at onsets ``onset``, periods ``per`` and widths ``width``
    (each (B, G): G candidates per series) explain in ``w`` (B, T) with one non-negative
    amplitude each: ``max(⟨w, s⟩, 0)² / ‖s‖²`` for the train ``s`` of impulses at every
    ``φ + k P`` (overlapping impulses add, as they do on the rail)."""
    n_steps = w.shape[1]
    # (B, G, T): samples since the last onset; an onset that falls on a sample is at it (the
    # rounding of the remainder would put it a period later)
    tau = (np.mod(np.arange(n_steps) - onset[..., None] + 1e-6, per[..., None]) - 1e-6
           ).astype(np.float32)
    per32 = per.astype(np.float32)[..., None]
    inv = (1.0 / width.astype(np.float32))[..., None]
    train = np.zeros(tau.shape, dtype=np.float32)
    for j in range(int(np.ceil(SUPPORT * float(np.max(width / per)))) + 1):
        v = (tau + j * per32) * inv  # the impulse j periods before the last one
        train += np.where(v <= SUPPORT, np.exp(-v * v), np.float32(0.0))
    b = np.einsum("bgt,bt->bg", train, w.astype(np.float32))
    return (np.maximum(b, 0.0) ** 2 / np.maximum((train * train).sum(axis=-1), 1e-12)
            ).astype(np.float64)


def best_of(w: F64, onset: F64, per: F64, width: F64) -> tuple[F64, F64, F64, F64]:
    """The candidate (onset, period, width; each (B, G), broadcast) that explains the most of
    each series, and that energy, all (B,); chunks of :data:`CHUNK` series."""
    onset, per, width = np.broadcast_arrays(onset, per, width)
    out = [np.empty(len(w)) for _ in range(4)]
    for i in range(0, len(w), CHUNK):
        part = slice(i, i + CHUNK)
        e = explained(w[part], onset[part], per[part], width[part])
        j = e.argmax(axis=1)
        rows = np.arange(len(j))
        for o, a in zip(out, (onset[part], per[part], width[part], e), strict=True):
            o[part] = a[rows, j]
    return out[0], out[1], out[2], out[3]


def coarse(w: F64, per: F64, reach: float = 1.0, step: float = 0.25, period_step: float = 0.1,
           min_period: float = 0.0) -> tuple[F64, F64]:
    """Per series (B,), the onset ``φ`` in ``[0, P)`` (``step`` samples apart) and the period
    (within ±``reach`` samples of ``per`` or of half of it, ``period_step`` apart, at least
    ``min_period``) whose first samples after the onsets ``φ + k P`` hold the largest sum of
    the jumps ``w[n] − w[n − 1]`` over its square root of terms (``w[−1]`` = 0: an impulse at
    the window's first sample is seen): an onset is an impulse's largest jump, whatever its
    width. The autocorrelation's period is a few tenths of a sample off, which over ten periods
    is more than an impulse's width, and can be twice the period where the impulses are wide.

    Sample ``n`` is the first after the onset ``φ + k P`` for the onsets in ``(n − 1, n]``: for
    each period the jumps are summed into bins of ``step`` by their phase ``n mod P``, and the
    onsets' sums are sums over the ``1 / step`` bins after theirs (around the circle)."""
    n_series, n_steps = w.shape
    jumps = np.diff(w, axis=1, prepend=0.0)
    offsets = np.arange(-reach, reach + 1e-9, period_step)
    p = np.concatenate([per[:, None] + offsets, 0.5 * per[:, None] + offsets], axis=1)
    p = np.maximum(p, max(min_period, 1.0))  # (B, Q): the candidate periods
    n_bins = int(np.ceil(p.max() / step)) + 1
    span = int(round(1.0 / step))
    bins_in = np.ceil(p / step - 1e-9).astype(np.int64)  # (B, Q): onset bins in [0, P)
    f = np.floor(np.mod(np.arange(n_steps), p[:, :, None]) / step).astype(np.int64)  # (B, Q, T)
    cell = (np.arange(p.size).reshape(p.shape)[:, :, None] * n_bins + f).ravel()
    hist = np.bincount(cell, np.broadcast_to(jumps[:, None, :], f.shape).ravel(),
                       minlength=p.size * n_bins).reshape(*p.shape, n_bins)
    ones = np.bincount(cell, minlength=p.size * n_bins).reshape(*p.shape, n_bins)
    # the bins from the onset's on, around the circle: the first bins again after the last
    # (every bin from ``bins_in`` on is empty), then sums of ``span`` neighbours
    ext = np.concatenate([np.stack([hist, ones]), np.zeros((2, *p.shape, span))], axis=3)
    put = bins_in[None, :, :, None] + np.arange(span)
    np.put_along_axis(ext, put, ext[..., :span], axis=3)
    cs = np.concatenate([np.zeros((2, *p.shape, 1)), np.cumsum(ext, axis=3)], axis=3)
    total, count = cs[..., span:span + n_bins] - cs[..., :n_bins]
    phase = np.arange(n_bins)
    score = np.where(phase < bins_in[:, :, None], total / np.sqrt(np.maximum(count, 1)), -np.inf)
    q, fb = np.unravel_index(score.reshape(n_series, -1).argmax(axis=1), hist.shape[1:])
    rows = np.arange(n_series)
    return fb * step, p[rows, q]


def refine(w: F64, onset: F64, per: F64, widths: F64) -> tuple[F64, F64, F64, F64]:
    """Step 3 of the module docstring from a coarse onset and period (B,): the width from the
    grid ``widths``; then three times, on grids finer each time, the onset of the window's
    middle impulse, the period about it (the middle onset and the period are nearly
    independent, where the first onset and the period are not) and the width. Returns onset,
    period, width and the energy explained (B,)."""
    col = np.newaxis
    onset, per, width, e = best_of(w, onset[:, col], per[:, col], widths[col, :])
    mid = np.floor(0.5 * w.shape[1] / per)[:, col]  # the middle impulse
    offsets = np.linspace(-1.0, 1.0, 11)
    for shift, stretch, scale in ((0.5, 0.15, 0.25), (0.2, 0.06, 0.125), (0.08, 0.024, 0.0625)):
        onset, per, width, e = best_of(w, onset[:, col] + shift * offsets, per[:, col],
                                       width[:, col])
        d = stretch * offsets
        onset, per, width, e = best_of(w, onset[:, col] - mid * d, per[:, col] + d,
                                       width[:, col])
        onset, per, width, e = best_of(w, onset[:, col], per[:, col],
                                       width[:, col] * 2.0 ** (scale * offsets[::2]))
    return onset, per, width, e


def impulses_fit(w: F64, onset: F64, per: F64, width: F64, ks: NDArray[np.int64], cap: float,
                 jitter: float = 1.0, steps: int = 17) -> F64:
    """Step 4 of the module docstring: the train at ``onset``, ``per`` and ``width`` (B,) fitted
    to ``w`` (B, T), impulse by impulse, each by the amplitude (``>= 0``, at most ``cap`` times
    the median of the train's) and the shift of its onset within ±``jitter`` samples (``steps``
    of them) that explain the most of what the other impulses leave, for :data:`SWEEPS`
    sweeps. The shift is for the sample an onset falls on: a narrow impulse one sample late
    leaves a spike of its height, and a period that drifts (a train that speeds up) moves the
    later onsets. Returns the fit (B, T)."""
    n_series, n_steps = w.shape
    starts = onset[:, None] + ks[None, :] * per[:, None]  # (B, K)
    length = int(np.ceil(SUPPORT * float(width.max()) + 2 * jitter)) + 2
    idx = np.floor(starts - jitter).astype(np.int64)[:, :, None] + np.arange(length)  # (B, K, L)
    idx = np.clip(idx, -length, n_steps + length - 1) + length  # in the padded residual
    shifts = np.linspace(-jitter, jitter, steps)
    u = (idx - length)[:, :, None, :] - (starts[:, :, None, None] + shifts[:, None])
    g = shape(u, width[:, None, None, None])  # (B, K, D, L)
    g *= ((idx >= length) & (idx < n_steps + length))[:, :, None, :]  # in the window only
    gg = np.maximum((g * g).sum(axis=-1), 1e-12)
    present = gg.max(axis=2) > 1e-9  # (B, K)
    e = np.pad(w, ((0, 0), (length, length)))  # what the train leaves
    a = np.zeros(starts.shape)
    pick = np.full(starts.shape, steps // 2)
    rows = np.arange(n_series)
    top = np.full(n_series, np.inf)  # the cap, from the second sweep on
    for _ in range(SWEEPS):
        for k in np.flatnonzero(present.any(axis=0)):
            at = idx[:, k]
            seg = e[rows[:, None], at] + a[:, k, None] * g[rows, k, pick[:, k]]
            b = np.einsum("bdl,bl->bd", g[:, k], seg)
            d = (np.maximum(b, 0.0) ** 2 / gg[:, k]).argmax(axis=1)
            amp = np.clip(b[rows, d] / gg[rows, k, d], 0.0, top)
            amp = np.where(present[:, k], amp, 0.0)
            e[rows[:, None], at] = seg - amp[:, None] * g[rows, k, d]
            a[:, k], pick[:, k] = amp, d
        some = (a > 0).any(axis=1)
        top[some] = cap * np.nanmedian(np.where(a[some] > 0, a[some], np.nan), axis=1)
    return w - e[:, length:length + n_steps]


def fit_train(w: F64, min_period: int, max_period: int, correlation: float,
              min_width: float, max_width: float, minimum: float, cap: float) -> Train:
    """The impulse train of every series of the whitened residual ``w`` (B, T) and whether it
    is taken out (module docstring)."""
    n_series, n_steps = w.shape
    zeros = np.zeros(n_series)
    onset, per, width, energy = zeros.copy(), zeros.copy(), zeros.copy(), zeros.copy()
    fit = np.zeros_like(w)
    kept = np.zeros(n_series, dtype=bool)
    if n_steps // 2 < min_period:  # not two periods in the window
        return Train(onset, per, width, energy, kept, fit)
    # a period at the range's first lag is not a peak there: the autocorrelation from two lags
    # before, and the period clipped back into the range
    p0, rho = period(w, max(2, min_period - 2), max_period)
    p0 = np.maximum(p0, min_period)
    rows = np.flatnonzero(rho >= correlation)
    if len(rows):
        ks = impulse_indices(n_steps, min_period - 0.5, max_width)
        widths = np.geomspace(min_width, max_width, int(np.ceil(
            2 * np.log2(max_width / min_width) - 1e-9)) + 1)  # steps of at most √2
        x = w[rows]
        o, p = np.empty(len(rows)), np.empty(len(rows))
        for i in range(0, len(rows), CHUNK):  # the coarse search's (series, periods, T) arrays
            part = slice(i, i + CHUNK)
            o[part], p[part] = coarse(x[part], p0[rows[part]], min_period=min_period - 0.5)
        o, p, wd, _ = refine(x, o, p, widths)
        model = impulses_fit(x, o, p, wd, ks, cap)
        e = (x * x).sum(axis=1) - ((x - model) ** 2).sum(axis=1)
        count = np.maximum(np.ceil(n_steps / p), 1)
        keep = e > minimum * count
        onset[rows], per[rows], width[rows], energy[rows], kept[rows] = o, p, wd, e, keep
        fit[rows] = np.where(keep[:, None], model, 0.0)
    return Train(onset, per, width, energy, kept, fit)
