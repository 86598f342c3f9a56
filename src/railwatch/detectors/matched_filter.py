"""Matched filter: the classical, training-light baseline (``docs/detectors.md``, "Reference
detectors: oracle and matched filter").

Per window and channel (a series ``x`` of ``T`` samples), all vectorised over the N·C series:

1. **Strip the sinusoid with a short robust linear predictor.** An autoregressive predictor of
   order ``p`` with intercept, ``x̂_t = Σ_k a_k x_{t−k} + b``, fitted by least squares on the
   window itself in both directions (forward and backward equations stacked, the "modified
   covariance" method, which suits sinusoids), made robust to the anomaly by iteratively
   reweighted least squares with Huber weights (scale = MAD of the residual). A sinusoid obeys an
   exact order-2 recursion; a larger ``p`` also follows the stage-2 frequency change, bursts and
   impulses, and averages the noise. The prediction error is ``e = c * x`` with the
   prediction-error filter ``c = (1, −a_1, …, −a_p)`` (forward residual for ``t ≥ p``, backward
   residual for the first ``p`` samples). The normal equations are loaded with a ridge of
   ``ridge`` (0.1) × their mean diagonal: a recording resampled to 100 Hz is empty above the
   anti-aliasing filter's 40 Hz, and an unloaded predictor whitens that empty band into large,
   unstable prediction-error filters (``docs/notes/2026-12-03-track-map-how-we-got-here.md``,
   "Where the per-pass loss came from": 78 % of the defect crossings in the top 1 % of their
   neighbourhood with 1e-6, 92 % with 0.1; on the benchmark's white-noise windows 0.1 is also
   slightly better).
2. **Noise level with one change point** (stage 4 changes the noise std once): the split of the
   residual's squared values (winsorised at 3 robust standard deviations, so the anomaly does not
   pick the split) into two constant-variance segments of maximal Gaussian likelihood; each
   segment's scale is the MAD of its residuals. ``w = e / σ_t``.
3. **Matched filters.** An anomaly ``d`` enters the residual as ``c * d``, so the filter matched to
   a box of ``L`` samples at ``s`` is ``h = c * box_L(s)``; ``<w, h> = Σ_{t∈box} (c ⋆ w)_t``,
   i.e. box sums of ``c ⋆ w`` (one correlation, then cumulative sums, as in the oracle), divided
   by ``‖c * box_L‖``. Spikes are ``L = 1``, local deviations ``L`` = 5..20. The two families are
   calibrated like the oracle's (``−log10`` family-wise p under N(0, 1),
   :mod:`railwatch.scoring.glr`), each box statistic attributed to the samples it covers.
4. **Standardise each channel by training statistics**: ``fit`` learns, per channel, the median and
   the MAD-based scale of the window maximum of that channel's raw score over the training
   windows (robust: the training set holds 10 % anomalies, whose huge scores would inflate a
   mean/std). Labels are never used.

Channel score (N, T, C) = standardised score; point = max over channels; instance = max over time.
No network, no context; works for any window length longer than ``2 p + 2`` samples.

**At field scale** (a recording at its own rate, ``railwatch train`` on a layout of scale
``field``; :meth:`MatchedFilter.field_scale`) the spec's sample counts still fit a squat (a spike
or a 2.5-10 ms box at 2 kHz) but not a weld or a corrugation patch: a 0.6-1.2 m dip makes the
wheel ring on the track at 30-100 Hz for 20-100 ms, whose box sums are near zero. Three
changes, chosen on the development physics tracks (docs/notes/2026-12-03-welds-and-texture.md):
the predictor remembers 8 ms (16 taps at 2 kHz: the P2 ringing is whitened, not followed); a
third family tests the **energy** of the whitened residual, ``Σ w²`` over boxes of 4-32 ms (the
GLR of a signal of any shape confined to the box, χ²; :func:`railwatch.scoring.glr.energy_z`),
calibrated like the others; and the noise scale is one per window, without the change point
(the benchmark's stage 4 changes the noise once; on a rail the change point cut a weld's
ringing off as a segment of its own and scaled it away). Welds of 0.3 mm or more found on one
pass: 42 % -> 77 %; corrugation 0 -> 75 %; false events per minute 0.49 -> 0.25.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from railwatch.detectors.api import (
    Detector,
    DetectorConfig,
    FloatArray,
    Scores,
    peak_standardized,
    peak_statistics,
)
from railwatch.errors import RailwatchError
from railwatch.scoring.glr import (
    Family,
    effective_counts,
    effective_energy_count,
    families,
    raise_to_energy,
    scale_counts,
    scan,
)
from railwatch.scoring.residual import MAD_TO_STD, masked_median

F64 = NDArray[np.float64]
#: At field scale (:meth:`MatchedFilter.field_scale`): the predictor's memory (s) and the
#: energy family's box durations (s).
FIELD_MEMORY_S = 0.008
FIELD_ENERGY_S = (0.004, 0.008, 0.016, 0.032)
CHUNK_BYTES = 4 << 20  # the predictors' design matrices of a chunk of windows (raw_scores)


@dataclass(frozen=True)
class MatchedFilterConfig(DetectorConfig):
    order: int = 8  # p: taps of the linear predictor
    huber_k: float = 1.345  # Huber threshold in robust standard deviations (95 % efficiency)
    irls_iterations: int = 4  # reweighting passes after the first least-squares fit
    ridge: float = 0.1  # relative ridge on the normal equations (module docstring, step 1)
    winsor: float = 3.0  # squared residuals clipped at (winsor · σ)² before the split search
    min_segment: int = 20  # shortest noise segment of the change-point split, samples
    min_box: int = 5  # shortest local deviation, samples (spec: 0.05 s at 100 Hz)
    max_box: int = 20  # longest local deviation, samples (spec: 0.2 s at 100 Hz)
    energy_boxes: tuple[int, ...] = ()  # lengths (samples) of the energy family (step 3); none:
    # off, as the spec's benchmark (field scale: :meth:`MatchedFilter.field_scale`)
    change_point: bool = True  # the noise scale of step 2 changes once per window (stage 4);
    # off: one scale per window (field scale: a defect's ringing is not a change of noise)
    null_windows: int = 10000  # Monte Carlo N(0, 1) windows calibrating each family
    null_alpha: float = 0.05  # tail level at which each family's calibration is exact

    def __post_init__(self) -> None:
        try:  # lengths given as text (--set, a saved model's JSON) become numbers
            object.__setattr__(self, "energy_boxes", tuple(int(L) for L in self.energy_boxes))
        except (TypeError, ValueError):
            pass  # MatchedFilter._energy says what is wrong, when the detector is used


# ----------------------------------------------------------------------------- the steps
def robust_ar(x: F64, order: int, huber_k: float, iterations: int, ridge: float) -> F64:
    """Huber-IRLS forward-backward least-squares predictor of every series.

    ``x`` (B, T) -> coefficients (B, p + 1): ``a_1 .. a_p`` then the intercept ``b``. Forward
    equations ``x_t ≈ Σ a_k x_{t−k} + b`` and backward ``x_t ≈ Σ a_k x_{t+k} + b`` (t over the
    valid range) share the coefficients; both are reweighted by Huber weights of their residuals.
    """
    p = order
    n_series, n = x.shape[0], x.shape[1] - p
    past = sliding_window_view(x, p + 1, axis=1)  # (B, T − p, p + 1): x_{t−p} .. x_t
    design = np.empty((n_series, 2 * n, p + 1))  # (B, R, p + 1), R = 2 (T − p)
    design[:, :n, :p] = past[:, :, p - 1::-1]  # forward rows
    design[:, n:, :p] = past[:, :, 1:]  # backward rows
    design[:, :, p] = 1.0  # intercept
    target = np.empty((n_series, 2 * n))  # (B, R)
    target[:, :n], target[:, n:] = past[:, :, p], past[:, :, 0]
    weights = np.ones_like(target)
    eye = np.eye(p + 1)
    weighted = np.empty_like(design)  # one buffer for every pass
    for it in range(iterations + 1):
        np.multiply(design, weights[:, :, None], out=weighted)  # (B, R, p + 1)
        gram = weighted.transpose(0, 2, 1) @ design  # (B, p + 1, p + 1)
        rhs = (weighted.transpose(0, 2, 1) @ target[:, :, None])[:, :, 0]  # (B, p + 1)
        scale = np.trace(gram, axis1=1, axis2=2)[:, None, None] / (p + 1)
        coef = np.linalg.solve(gram + ridge * scale * eye + 1e-12 * eye, rhs[..., None])[..., 0]
        if it == iterations:
            break
        resid = target - (design @ coef[:, :, None])[:, :, 0]
        sigma = MAD_TO_STD * np.median(np.abs(resid), axis=1, keepdims=True) + 1e-12
        weights = np.minimum(1.0, huber_k * sigma / np.maximum(np.abs(resid), 1e-300))
    return coef


def prediction_error(x: F64, coef: F64) -> F64:
    """Residual ``e`` (B, T) of the predictor: forward for ``t ≥ p``, backward for ``t < p``."""
    p = coef.shape[1] - 1
    a, b = coef[:, :p], coef[:, p:]
    past = sliding_window_view(x, p + 1, axis=1)  # (B, T − p, p + 1)
    fwd = past[:, :, p] - np.einsum("btk,bk->bt", past[:, :, p - 1::-1], a) - b  # t = p .. T−1
    bwd = past[:, :p, 0] - np.einsum("btk,bk->bt", past[:, :p, 1:], a) - b  # t = 0 .. p−1
    return np.concatenate([bwd, fwd], axis=1)


def error_filter(coef: F64) -> F64:
    """The prediction-error filter ``c = (1, −a_1, …, −a_p)`` (B, p + 1) of the predictor's
    coefficients (:func:`robust_ar`; the intercept left out)."""
    return np.concatenate([np.ones((len(coef), 1)), -coef[:, :-1]], axis=1)


def noise_scale(e: F64, min_segment: int, winsor: float) -> F64:
    """Per-sample robust noise std (B, T) with one change point (spec stage 4).

    The split ``k`` maximises the two-segment Gaussian likelihood of the winsorised squared
    residuals, ``−k log v̂₁ − (T − k) log v̂₂``; each segment's scale is then ``1.4826 · MAD``.
    Windows shorter than ``2 · min_segment`` get one scale.
    """
    n_series, n_steps = e.shape
    sigma = MAD_TO_STD * np.median(np.abs(e), axis=1, keepdims=True) + 1e-12  # (B, 1)
    if n_steps < 2 * min_segment:
        return np.broadcast_to(sigma, e.shape).copy()
    u = np.minimum(e**2, (winsor * sigma) ** 2)
    cs = np.cumsum(u, axis=1)  # (B, T)
    k = np.arange(min_segment, n_steps - min_segment + 1)  # candidate first-segment lengths
    left, right = cs[:, k - 1] / k, (cs[:, -1:] - cs[:, k - 1]) / (n_steps - k)
    loglik = -k * np.log(left + 1e-300) - (n_steps - k) * np.log(right + 1e-300)
    split = k[np.argmax(loglik, axis=1)][:, None]  # (B, 1)
    first = np.arange(n_steps)[None, :] < split  # (B, T)
    absdev = np.abs(e)
    s1, s2 = masked_median(absdev, first), masked_median(absdev, ~first)
    return MAD_TO_STD * np.where(first, s1, s2) + 1e-12


def filter_correlate(w: F64, c: F64) -> F64:
    """``(c ⋆ w)_u = Σ_k c_k w_{u+k}`` (B, T), with ``w`` zero beyond the window."""
    n_taps = c.shape[1]
    padded = np.concatenate([w, np.zeros((w.shape[0], n_taps - 1))], axis=1)
    return np.einsum("btk,bk->bt", sliding_window_view(padded, n_taps, axis=1), c)


def template_norm(c: F64, length: int) -> F64:
    """``‖c * box_L‖`` (B,) from the autocorrelation ρ of ``c``: ``Σ_{|k|<L} (L − |k|) ρ_|k|``.

    >>> round(float(template_norm(np.array([[1.0, -1.0]]), 5)[0] ** 2), 9)  # step up, step down
    2.0
    """
    return template_norms(c, (length,))[0]


def template_norms(c: F64, lengths: tuple[int, ...]) -> list[F64]:
    """:func:`template_norm` of every length, the autocorrelation of ``c`` computed once."""
    n_taps = c.shape[1]
    lags = np.arange(min(n_taps, max(lengths)))
    rho = np.stack([(c[:, : n_taps - k] * c[:, k:]).sum(axis=1) for k in lags], axis=1)
    out = []
    for length in lengths:
        near = lags[:min(n_taps, length)]
        weight = np.where(near == 0, length, 2 * (length - near)).astype(np.float64)
        out.append(np.sqrt(np.maximum(rho[:, :len(near)] @ weight, 1e-12)))
    return out


# ----------------------------------------------------------------------------- the detector
class MatchedFilter(Detector):
    """Robust linear predictor + one-change-point noise level + spike/box matched filters."""

    Config: ClassVar[type[DetectorConfig]] = MatchedFilterConfig
    config: MatchedFilterConfig  # type: ignore[assignment]
    fixed_length: ClassVar[bool] = False  # per-window fits; the calibration rescales to any T

    def _families(self) -> tuple[Family, ...]:
        cfg = self.config
        if not 1 < cfg.min_box <= cfg.max_box:
            raise RailwatchError(
                f"need 1 < min_box <= max_box, got min_box={cfg.min_box}, max_box={cfg.max_box}"
            )
        if cfg.order < 1:
            raise RailwatchError(f"order must be at least 1, got {cfg.order}")
        self._energy()
        return families(cfg.min_box, cfg.max_box)

    def _energy(self) -> Family:
        """The energy family's lengths (samples), checked (the config made numbers of them
        where it could)."""
        lengths = self.config.energy_boxes
        if not all(isinstance(L, int) and L >= 2 for L in lengths):
            raise RailwatchError("energy_boxes must be box lengths of at least 2 samples, e.g. "
                                 f"8,16,32,64; got {','.join(map(str, lengths))}")
        return lengths

    @classmethod
    def field_scale(cls, fs: float) -> dict[str, Any]:
        """At field scale (a recording's own rate ``fs``): a predictor that remembers
        :data:`FIELD_MEMORY_S` (8 to 32 taps), the energy family over :data:`FIELD_ENERGY_S`,
        one noise scale per window (module docstring, "At field scale")."""
        order = int(np.clip(round(FIELD_MEMORY_S * fs), 8, 32))
        energy = tuple(sorted({max(2, round(d * fs)) for d in FIELD_ENERGY_S}))
        return {"order": order, "energy_boxes": energy, "change_point": False}

    def raw_scores(self, X: FloatArray) -> NDArray[np.floating]:
        """Unstandardised channel scores (N, T, C): calibrated −log10 family-wise p.

        Vectorised over chunks of windows whose predictor design matrices (chunk · C,
        2 (T − p), p + 1) fill about :data:`CHUNK_BYTES`: they stay in a core's cache. At 2 kHz
        (T = 1179, p = 16, two channels) that is 6 windows a chunk; 256, as before 2026-12-05,
        made `detect` a fifth slower (docs/notes/2026-12-05-detect-speed.md).
        """
        cfg = self.config
        n, n_steps, n_channels = X.shape
        if n_steps < 2 * cfg.order + 2:
            raise RailwatchError(
                f"windows of {n_steps} steps are too short for a predictor of order {cfg.order}: "
                f"need at least {2 * cfg.order + 2} (lower order)"
            )
        per_series = 2 * (n_steps - cfg.order) * (cfg.order + 1) * 8  # bytes of its design
        step = max(1, CHUNK_BYTES // (per_series * n_channels))
        return np.concatenate([self._raw_chunk(X[i:i + step]) for i in range(0, n, step)])

    def _raw_chunk(self, X: FloatArray) -> NDArray[np.floating]:
        cfg = self.config
        n, n_steps, n_channels = X.shape
        fams = self._families()
        x = X.transpose(0, 2, 1).reshape(n * n_channels, n_steps).astype(np.float64)  # (B, T)
        coef = robust_ar(x, cfg.order, cfg.huber_k, cfg.irls_iterations, cfg.ridge)
        e = prediction_error(x, coef)  # (B, T)
        w = e / noise_scale(e, cfg.min_segment if cfg.change_point else n_steps, cfg.winsor)
        c = error_filter(coef)  # (B, p + 1)
        g = filter_correlate(w, c)
        to_ntc = (n, n_channels, 1)
        norms = [[v.reshape(to_ntc).transpose(0, 2, 1) for v in template_norms(c, fam)]
                 for fam in fams]  # each (N, 1, C)
        g = g.reshape(n, n_channels, n_steps).transpose(0, 2, 1)  # (N, T, C)
        counts = scale_counts(self.stats_["null_counts"], fams, self.n_steps_, n_steps)
        out = scan(g, fams, norms, counts)
        energy = self._energy()
        if energy:
            raise_to_energy(out, w.reshape(n, n_channels, n_steps).transpose(0, 2, 1), energy,
                            self.stats_["energy_count"], self.n_steps_)
        return out

    def _fit(self, X: FloatArray, context: dict[str, FloatArray]) -> None:
        cfg = self.config
        self.stats_["null_counts"] = effective_counts(
            self.n_steps_, self._families(), cfg.null_windows, cfg.null_alpha, cfg.seed)
        energy = self._energy()
        if energy:
            self.stats_["energy_count"] = np.array([effective_energy_count(
                self.n_steps_, energy, cfg.null_windows, cfg.null_alpha, cfg.seed)])
        self.stats_.update(peak_statistics(self.raw_scores(X)))

    def _score(self, X: FloatArray, context: dict[str, FloatArray], extras: bool) -> Scores:
        return peak_standardized(self.raw_scores(X), self.stats_)
