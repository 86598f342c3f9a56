"""The harmonic nuisance model: a window's running vibration as one sinusoid whose amplitude and
phase drift slowly (``railwatch.detectors.nuisance_glr``).

A train's running vibration is narrow-band: the synthetic runs' base sinusoid has a frequency
and amplitude proportional to speed, and the speed changes over tens of seconds, so within a
2-s window the frequency drifts by a few percent. The model of one series ``x`` (T samples) is

    x̂_t = b₀ + b₁ τ + Σ_{j=0..poly} τ^j (a_j sin φ_t + c_j cos φ_t),   τ = t / T − 1/2,

with the phase ``φ_t`` of a frequency that changes linearly (a train that accelerates): the peak
of the series' tapered spectrum at the centre (refined between bins), changing at the rate
that the peaks of the window's two halves give; and the amplitudes ``a_j, c_j`` polynomials in
time, so that a slow drift of amplitude and of phase stays in the model
(``sin(φ + θ(τ)) = cos θ sin φ + sin θ cos φ``). It is fitted by Huber-weighted least
squares (iteratively reweighted), so that a defect, a few samples long, does not pull it. Unlike
a linear predictor's whitening, which also notches out the band around ``ω`` and with it much of
a box's energy, the model takes away a subspace of ``2 (poly + 1) + 2`` smooth directions and
leaves a box of 5-20 samples in 200 nearly whole.

The paper's windows change speed at one instant instead (stages 2-8: the frequency ×0.5-1.5):
:func:`phase_break` finds the instant as the kink of the oscillation's phase, and
:func:`harmonic_fit` with ``change`` gives each side a sinusoid of its own.

A vibration that repeats but is not a sinusoid (a wheel out of round, a clipped or rectified
wave) has power at the harmonics of its fundamental: :func:`harmonic_fit` with ``overtones``
adds the 2nd, 3rd, ... harmonics (:func:`overtone_design`) where a likelihood-ratio test keeps
them (:func:`with_overtones`), so that a sinusoid keeps its smaller model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railwatch.scoring.residual import MAD_TO_STD

F64 = NDArray[np.float64]
#: The band around a window's spectral peak whose phase :func:`phase_break` follows: the paper's
#: speed change multiplies the frequency by 0.5-1.5 (a factor of up to 3 between the two sides);
#: a factor of 2 each way keeps most of both and drops most of the noise.
BAND = 2.0
#: A change of frequency under this share of the faster side's is left to the chirp of the first
#: model (a train accelerating at 0.5 m/s² changes it by 3 % in 1 s at 15 m/s).
MIN_JUMP = 0.03


#: The overtones' likelihood-ratio test: the chi-square quantile their columns' drop of the
#: residual's clipped power must reach, in noise variances, per column (a false keep on 1 in
#: 10,000 white-noise series with 4 columns: 23.5 / 4).
OVERTONE_CHI2 = 5.9


def dominant_frequency(x: F64, min_cycles: float = 0.5, taper: F64 | None = None) -> F64:
    """The frequency (cycles per sample) of each series' largest spectral peak (B,), from the
    Hann-tapered, mean-removed series zero-padded to at least 4 T, refined by a parabola
    through the log magnitudes of the peak bin and its neighbours; peaks under ``min_cycles``
    cycles per window are ignored (the intercept and trend take those). ``taper`` (B, T), if
    given, replaces the Hann window (a segment's own: :func:`segment_taper`), and
    ``min_cycles`` then counts cycles over the taper's support."""
    n_series, n = x.shape
    nfft = 1 << int(np.ceil(np.log2(4 * n)))
    if taper is None:
        taper = np.broadcast_to(np.hanning(n), x.shape)
        span = np.full(n_series, float(n))
    else:
        span = np.maximum((taper > 0).sum(axis=1), 1.0)
    mean = (x * taper).sum(axis=1, keepdims=True) / np.maximum(taper.sum(axis=1, keepdims=True),
                                                                1e-300)
    spec = np.abs(np.fft.rfft((x - mean) * taper, nfft))
    bins = np.arange(spec.shape[1])
    spec[bins[None, :] < np.ceil(min_cycles * nfft / span)[:, None]] = 0.0
    spec[:, 0] = 0.0
    k = np.clip(np.argmax(spec, axis=1), 1, spec.shape[1] - 2)
    rows = np.arange(n_series)
    a, b, c = (np.log(spec[rows, k + d] + 1e-300) for d in (-1, 0, 1))
    den = a - 2 * b + c
    shift = np.where(den < 0, 0.5 * (a - c) / np.where(den < 0, den, -1.0), 0.0)
    return (k + np.clip(shift, -0.5, 0.5)) / nfft


def segment_taper(n: int, start: NDArray[np.int64], stop: NDArray[np.int64]) -> F64:
    """Hann windows (B, n) over ``[start, stop)`` of each series, zero elsewhere."""
    t = np.arange(n)[None, :]
    length = (stop - start)[:, None].astype(np.float64)
    u = (t - start[:, None] + 0.5) / length
    inside = (t >= start[:, None]) & (t < stop[:, None])
    return np.where(inside, 0.5 - 0.5 * np.cos(2 * np.pi * u), 0.0)


def chirp_rate(x: F64, freq: F64, max_drift: float = 0.15, min_cycles: float = 3.0) -> F64:
    """The change of frequency per sample (cycles per sample², B,) from the spectral peaks of
    the window's two halves near ``freq``: ``(f₂ − f₁) / (T / 2)``; 0 where the window holds
    under ``min_cycles`` cycles or the halves differ by more than ``max_drift`` of ``freq``."""
    n = x.shape[1]
    half = n // 2
    f1, f2 = (dominant_frequency(part, 0.5) for part in (x[:, :half], x[:, n - half:]))
    drift = f2 - f1
    ok = (freq * n >= min_cycles) & (np.abs(drift) <= max_drift * freq)
    return np.where(ok, drift / (n - half), 0.0)


def powers(n: int, degree: int) -> F64:
    """``τ^k`` for k = 0..degree (n, degree + 1), ``τ = t / n − 1/2``: the model's time axis."""
    tau = np.arange(n, dtype=np.float64) / n - 0.5
    return tau[:, None] ** np.arange(degree + 1)[None, :]


@dataclass(frozen=True)
class Design:
    """A design matrix (B, n, P) whose columns are a carrier times a power of time: carrier c
    (B, n; None: the constant 1) times ``τ^j`` for j = 0..``degrees[c]``.

    The model's columns are all of this kind (``τ^j sin φ_t``, ``τ^j cos φ_t``, the intercept
    and trend), so the weighted normal equations need only the weighted sums of each pair of
    carriers times ``τ^k``: one (B, n) product and one (B, n) @ (n, k) product per pair,
    instead of a weighted (B, n, P) matrix and its (B, P, P) Gram matrix per reweighting.
    :meth:`dense` is the matrix itself."""

    carriers: tuple[F64 | None, ...]
    degrees: tuple[int, ...]
    n: int

    @property
    def width(self) -> int:
        """P, the number of columns."""
        return sum(d + 1 for d in self.degrees)

    def __add__(self, other: Design) -> Design:
        """The columns of both."""
        return Design(self.carriers + other.carriers, self.degrees + other.degrees, self.n)

    def rows(self, k: NDArray[np.int64]) -> Design:
        """The design of the series ``k``."""
        return Design(tuple(None if c is None else c[k] for c in self.carriers), self.degrees,
                      self.n)

    def blocks(self) -> list[tuple[int, int, int, int, F64 | None]]:
        """(column offset of carrier c, of d, degree of c, of d, carrier c × d or None for the
        constant) for every pair c <= d, the products made once (cached)."""
        if "_blocks" not in self.__dict__:
            offsets = np.cumsum((0,) + tuple(d + 1 for d in self.degrees))
            out = []
            for c, (a, da) in enumerate(zip(self.carriers, self.degrees, strict=True)):
                for d in range(c, len(self.carriers)):
                    b, db = self.carriers[d], self.degrees[d]
                    product = b if a is None else a if b is None else a * b
                    if product is None or product.any():  # disjoint masks: a block of zeros
                        out.append((int(offsets[c]), int(offsets[d]), da, db, product))
            object.__setattr__(self, "_blocks", out)
        return self.__dict__["_blocks"]  # type: ignore[no-any-return]

    def normal_equations(self, weights: F64, y: F64) -> tuple[F64, F64]:
        """``Dᵀ W D`` (B, P, P) and ``Dᵀ W y`` (B, P) for the weights ``W`` (B, n)."""
        p = powers(self.n, 2 * max(self.degrees))
        gram = np.zeros((len(y), self.width, self.width))
        rhs = np.empty((len(y), self.width))
        wy = weights * y
        for oc, od, dc, dd, product in self.blocks():
            moments = (weights if product is None else weights * product) @ p[:, :dc + dd + 1]
            block = moments[:, np.arange(dc + 1)[:, None] + np.arange(dd + 1)[None, :]]
            gram[:, oc:oc + dc + 1, od:od + dd + 1] = block
            gram[:, od:od + dd + 1, oc:oc + dc + 1] = block.transpose(0, 2, 1)
        offset = 0
        for a, da in zip(self.carriers, self.degrees, strict=True):
            rhs[:, offset:offset + da + 1] = (wy if a is None else wy * a) @ p[:, :da + 1]
            offset += da + 1
        return gram, rhs

    def evaluate(self, coef: F64) -> F64:
        """``D @ coef`` (B, n) for coefficients (B, P)."""
        p = powers(self.n, max(self.degrees))
        out = np.zeros((len(coef), self.n))
        offset = 0
        for a, da in zip(self.carriers, self.degrees, strict=True):
            poly = coef[:, offset:offset + da + 1] @ p[:, :da + 1].T
            out += poly if a is None else poly * a
            offset += da + 1
        return out

    def dense(self) -> F64:
        """The matrix (B, n, P), columns carrier by carrier, power by power."""
        p = powers(self.n, max(self.degrees))
        columns = [p[None, :, j] * (1.0 if a is None else a)
                   for a, da in zip(self.carriers, self.degrees, strict=True)
                   for j in range(da + 1)]
        batch = next((len(a) for a in self.carriers if a is not None), 1)
        return np.stack([np.broadcast_to(c, (batch, self.n)) for c in columns], axis=2)


def oscillation(n: int, freq: F64, rate: F64 | None = None) -> tuple[F64, F64]:
    """``sin φ_t`` and ``cos φ_t`` (B, n) of :func:`harmonic_design`'s phase."""
    t = np.arange(n, dtype=np.float64)
    phase = 2 * np.pi * freq[:, None] * t[None, :]  # (B, n)
    if rate is not None:
        phase += np.pi * rate[:, None] * (t - (n - 1) / 2)[None, :] ** 2
    return np.sin(phase), np.cos(phase)


def harmonic_design(n: int, freq: F64, poly: int, rate: F64 | None = None,
                    mask: NDArray[np.bool_] | None = None) -> Design:
    """The model's design: intercept and trend, then ``τ^j sin φ_t`` and ``τ^j cos φ_t`` for
    j = 0..poly, with ``φ_t = 2π (f t + r (t − c)² / 2)`` for a frequency that changes by
    ``rate`` r per sample (``freq`` f (B,) at the centre c). With ``mask`` (B, n), the harmonic
    columns only: zero outside it (a segment's sinusoid)."""
    sin, cos = oscillation(n, freq, rate)
    if mask is not None:
        return Design((sin * mask, cos * mask), (poly, poly), n)
    return Design((None, sin, cos), (1, poly, poly), n)


def overtone_design(sin1: F64, cos1: F64, freq: F64, overtones: int) -> Design:
    """``sin k φ_t`` and ``cos k φ_t`` for k = 2..overtones + 1 (constant amplitudes) from a
    design's ``sin φ_t`` and ``cos φ_t`` carriers (B, n), by the angle-addition recurrence;
    zero where k f is within a tenth of the Nyquist frequency or above (``freq`` (B,))."""
    carriers = []
    sin_k, cos_k = sin1, cos1
    for k in range(2, overtones + 2):
        sin_k, cos_k = sin_k * cos1 + cos_k * sin1, cos_k * cos1 - sin_k * sin1
        below = (k * freq < 0.45)[:, None]
        carriers += [sin_k * below, cos_k * below]
    return Design(tuple(carriers), (0,) * len(carriers), sin1.shape[1])


def robust_fit(x: F64, design: Design, huber_k: float = 1.345, iterations: int = 2,
               level: F64 | None = None) -> tuple[F64, F64]:
    """Huber-IRLS least squares of every series ``x`` (B, T) on its ``design``: the fit (B, T)
    and the robust scale (B,) that sets the Huber threshold, 1.4826 MAD of the least-squares
    residual (held through the reweightings: one median per series).

    With ``level`` (B, T), the fit is weighted least squares, of ``x / level`` on the design
    divided by it, and the scale returned is that of ``(x − fit) / level``; the Huber threshold
    is set on ``x − fit``, the series' own units: what the model does not hold (a defect, an
    impulse, a burst) is as large on quiet track as on loud, and measured against the noise of
    quiet track every impulse there would be an outlier."""
    eye = np.eye(design.width)
    inverse2 = None if level is None else 1.0 / (level * level)
    weights = np.ones_like(x) if inverse2 is None else inverse2
    fit = np.zeros_like(x)
    sigma = np.ones(len(x))
    cut = sigma
    for it in range(iterations + 1):
        gram, rhs = design.normal_equations(weights, x)
        scale = np.trace(gram, axis1=1, axis2=2)[:, None, None] / len(eye)
        coef = np.linalg.solve(gram + 1e-9 * scale * eye + 1e-300 * eye, rhs[:, :, None])
        fit = design.evaluate(coef[:, :, 0])
        if it == iterations:
            break
        resid = x - fit
        if it == 0:
            cut = MAD_TO_STD * np.median(np.abs(resid), axis=1) + 1e-12
            sigma = cut if level is None else \
                MAD_TO_STD * np.median(np.abs(resid / level), axis=1) + 1e-12
        weights = np.minimum(1.0, huber_k * cut[:, None] / np.maximum(np.abs(resid), 1e-300))
        if inverse2 is not None:
            weights *= inverse2
    return fit, sigma


def phase_break(x: F64, min_segment: int, step: int = 2, edge: int = 8, band: float = BAND,
                freq: F64 | None = None) -> tuple[NDArray[np.int64], F64]:
    """Where the frequency of each series' oscillation changes (B,), and by what share of the
    faster side's (B,): the breakpoint of the
    continuous two-piece line that fits the unwrapped phase of its analytic signal best (least
    squares, candidates every ``step`` samples at least ``min_segment`` from either end; the
    ``edge`` samples at each end, which the transform bends, left out). The analytic signal is
    taken of the band ``(f / band, f · band)`` around the series' spectral peak f only, so that
    the noise elsewhere does not turn its phase. A jump of frequency is a kink of the phase,
    whatever the noise level and the amplitude do. ``freq``: the series' spectral peaks, if
    known."""
    n = x.shape[1]
    freqs = np.fft.fftfreq(n)[None, :]
    peak = (dominant_frequency(x) if freq is None else freq)[:, None]
    keep = (freqs > peak / band) & (freqs < peak * band)  # positive frequencies only
    analytic = np.fft.ifft(np.where(keep, 2 * np.fft.fft(x, axis=1), 0), axis=1)
    phase = np.unwrap(np.angle(analytic), axis=1)
    y = phase[:, edge:n - edge]
    t = np.arange(edge, n - edge, dtype=np.float64)
    ks = np.arange(min_segment, n - min_segment + 1, step)
    # Least squares on [1, t, (t − k)₊] for every k at once: the normal equations' matrix does
    # not depend on the series, and Σ (t − k)₊ y = Σ_{t>k} t y − k Σ_{t>k} y from suffix sums.
    hinge = np.maximum(t[None, :] - ks[:, None], 0.0)  # (K, T')
    ones = np.ones_like(t)
    gram = np.empty((len(ks), 3, 3))
    for i, a in enumerate((ones, t)):
        for j, b in enumerate((ones, t)):
            gram[:, i, j] = a @ b
        gram[:, i, 2] = gram[:, 2, i] = hinge @ a
    gram[:, 2, 2] = (hinge ** 2).sum(axis=1)
    inverse = np.linalg.inv(gram)  # (K, 3, 3)
    suffix_y = np.cumsum(y[:, ::-1], axis=1)[:, ::-1]  # Σ_{t' ≥ t} y
    suffix_ty = np.cumsum((y * t)[:, ::-1], axis=1)[:, ::-1]
    after = np.searchsorted(t, ks, side="right")  # first t > k
    inside = after < len(t)
    at = np.minimum(after, len(t) - 1)
    hy = np.where(inside, suffix_ty[:, at] - ks * suffix_y[:, at], 0.0)  # (B, K)
    rhs = np.stack([np.broadcast_to(y.sum(axis=1, keepdims=True), hy.shape),
                    np.broadcast_to((y * t).sum(axis=1, keepdims=True), hy.shape), hy], axis=2)
    explained = np.einsum("bki,kij,bkj->bk", rhs, inverse, rhs)
    best = np.argmax(explained, axis=1)
    rows = np.arange(len(x))
    coef = np.einsum("bij,bj->bi", inverse[best], rhs[rows, best])  # (B, 3): a, slope, change
    before, after = coef[:, 1], coef[:, 1] + coef[:, 2]
    share = np.abs(coef[:, 2]) / np.maximum(np.maximum(np.abs(before), np.abs(after)), 1e-300)
    return ks[best], share


def harmonic_fit(x: F64, poly: int = 2, huber_k: float = 1.345, iterations: int = 3,
                 min_cycles: float = 0.5, chirp: bool = True, change: float = 0.0,
                 min_segment: int = 20, overtones: int = 0, level: F64 | None = None) -> F64:
    """The fitted model x̂ (B, T) of every series ``x`` (B, T): the module docstring's model at
    :func:`dominant_frequency` (with ``chirp``, changing at :func:`chirp_rate`), by least
    squares then ``iterations`` Huber reweightings (threshold ``huber_k`` robust standard
    deviations of the residual).

    With ``change`` > 0, a speed that changes at one instant (the paper's stages 2-8): each side
    of the window's :func:`phase_break` gets a sinusoid of its own frequency (amplitude and
    phase drifting linearly), the intercept and trend shared; that model replaces the first
    where it lowers the residual's power (squares clipped at 9 robust variances of the first
    model's, so that a defect weighs the same in both) by more than the share ``change`` of
    its rms.

    With ``overtones`` K > 0, a vibration that is periodic but not a sinusoid: the model with
    the fundamental's 2nd to (K + 1)th harmonics (one sine and cosine each) replaces the first
    where the likelihood-ratio test says so (:func:`with_overtones`).

    With ``level`` (B, T), the noise's std at every sample up to a factor per series (a noise
    floor's shape in time), everything is done on the series divided by it: the spectral peaks
    and the fits (weighted least squares, the Huber threshold in the series' own units:
    :func:`robust_fit`), the tests in noise variances. A window half on quiet and half on loud
    track is fitted where the noise lets the vibration be seen; unweighted, its loud half's
    noise can outweigh a weak vibration's spectral peak and the model then fits noise."""
    divided = x if level is None else x * (1.0 / level)  # for the spectral peaks and tests
    freq = dominant_frequency(divided, min_cycles)
    rate = chirp_rate(divided, freq) if chirp else None
    sin, cos = oscillation(x.shape[1], freq, rate)
    design = Design((None, sin, cos), (1, poly, poly), x.shape[1])
    fit, sigma = robust_fit(x, design, huber_k, iterations, level)
    if overtones > 0:
        more = overtone_design(sin, cos, freq, overtones)
        fit = with_overtones(x, fit, sigma, design, more, huber_k, iterations, level)
    if change > 0 and x.shape[1] >= 2 * min_segment:
        split, share = phase_break(divided, min_segment, freq=freq)
        jumps = np.flatnonzero(share >= MIN_JUMP)  # the others keep the first model
        if len(jumps):
            fit = two_sided(x, fit, sigma, jumps, split[jumps], change, huber_k, iterations,
                            min_cycles, level)
    return fit


def two_sided(x: F64, fit: F64, sigma: F64, jumps: NDArray[np.int64], split: NDArray[np.int64],
              change: float, huber_k: float, iterations: int, min_cycles: float,
              level: F64 | None) -> F64:
    """:func:`harmonic_fit`'s ``fit`` (B, T) replaced, on the series ``jumps`` whose frequency
    changes at ``split``, by a sinusoid on either side (an intercept and trend shared) where
    that lowers the residual's clipped power (over ``level`` when given, ``sigma`` its robust
    scale) by the share ``change`` of its rms."""
    n = x.shape[1]
    x2, level2 = x[jumps], None if level is None else level[jumps]
    divided = x2 if level2 is None else x2 * (1.0 / level2)
    design = Design((None,), (1,), n)  # the shared intercept and trend
    for lo, hi in ((np.zeros_like(split), split), (split, np.full_like(split, n))):
        taper = segment_taper(n, lo, hi)
        design += harmonic_design(n, dominant_frequency(divided, min_cycles, taper), 1, None,
                                  taper > 0)
    fit2, _ = robust_fit(x2, design, huber_k, iterations, level2)
    clip = (3 * sigma[jumps, None]) ** 2  # a defect counts the same in both

    def power(fitted: F64) -> F64:
        r = x2 - fitted
        return np.minimum((r if level2 is None else r / level2) ** 2, clip).mean(axis=1)

    better = power(fit2) < (1 - change) ** 2 * power(fit[jumps])
    fit[jumps[better]] = fit2[better]
    return fit


def with_overtones(x: F64, fit: F64, sigma: F64, design: Design, overtones: Design,
                   huber_k: float, iterations: int, level: F64 | None = None) -> F64:
    """``fit`` (B, T) of ``design`` replaced by the fit on ``design`` and its ``overtones``
    (:func:`overtone_design`) where that lowers the residual's power (over ``level`` when
    given), squares clipped at 9 robust variances ``sigma²`` (a defect weighs the same in
    both), by more than :data:`OVERTONE_CHI2` noise variances per added column: the
    likelihood-ratio test of the overtones, which a sinusoid in white noise passes about once
    in 10,000 series. Only the series where the overtones alone explain half of that of the
    first fit's clipped residual (least squares) are fitted again."""
    added = sum((np.abs(c).sum(axis=1) > 0) for c in overtones.carriers if c is not None)
    need = OVERTONE_CHI2 * np.maximum(added, 1) * sigma ** 2
    units = np.ones_like(x) if level is None else level
    r = np.clip((x - fit) / units, -3 * sigma[:, None], 3 * sigma[:, None])
    gram, rhs = overtones.normal_equations(1.0 / (units * units), r * units)
    scale = np.trace(gram, axis1=1, axis2=2)[:, None, None] + 1e-300
    coef = np.linalg.solve(gram + 1e-9 * scale * np.eye(gram.shape[1]), rhs[:, :, None])
    rows = np.flatnonzero((rhs * coef[:, :, 0]).sum(axis=1) > 0.5 * need)
    if not len(rows):
        return fit
    richer, _ = robust_fit(x[rows], design.rows(rows) + overtones.rows(rows), huber_k,
                           iterations, None if level is None else level[rows])
    clip = (3 * sigma[rows, None]) ** 2
    drop = (np.minimum(((x[rows] - fit[rows]) / units[rows]) ** 2, clip)
            - np.minimum(((x[rows] - richer) / units[rows]) ** 2, clip)).sum(axis=1)
    out = fit.copy()
    keep = drop > need[rows]
    out[rows[keep]] = richer[keep]
    return out
