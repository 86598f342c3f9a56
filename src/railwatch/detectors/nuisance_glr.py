"""nuisance-glr: the GLR test of the oracle on a residual whose nuisance is modelled, not learned
(``docs/nuisance-glr.md``).

The oracle knows each window's nuisance signal and noise level and tests the whitened residual
for a spike or a box. This detector puts explicit estimates in their place, per window and
channel (vectorised over the N·C series, chunks of windows on up to two threads):

1. **Nuisance**: the harmonic model of :mod:`railwatch.scoring.harmonic`, a sinusoid at the
   window's spectral peak whose frequency changes linearly (``chirp``) and whose amplitude and
   phase drift as quadratics in time, plus an intercept and a trend, fitted by Huber-weighted
   least squares; its 2nd .. (``overtones`` + 1)th harmonics where a likelihood-ratio test
   keeps them (a periodic vibration that is not a sinusoid); where the frequency jumps at one
   instant (the paper's speed change), a sinusoid of its own on each side of the jump, found as
   the kink of the oscillation's phase, when that lowers the residual's rms by ``change``.
   With a noise floor (step 2) and ``floor_weights``, fitted to the series divided by the
   floor's shape (weighted least squares; the Huber threshold in the series' own units).
2. **Noise level**: where ``detect`` hands it the recording's noise floor
   (:mod:`railwatch.recordings.floor`: the level measured in the band that the resampling
   throws away), the residual is divided by its running median over ±``floor_span`` samples,
   so that the level may step anywhere in the window; without a floor, by a level with at most
   one change per window (:func:`railwatch.scoring.residual.changepoint_scale`, the paper's
   stage 4). Then by the robust scale (1.4826 MAD) of what is left, one per window.
3. **Bursts** (:mod:`railwatch.scoring.bursts`): the best short oscillation around the whitened
   residual's energy peak is taken out where it explains more than a box or a spike there (by
   ``burst_margin`` and the share ``burst_ratio``), and the level is measured again without it;
   then once more where one was taken out (``burst_count``: a second burst in the window).
4. **Periodic impulses** (:mod:`railwatch.scoring.periodic`): where the residual repeats at a
   period of ``min_period``-``max_period`` samples (autocorrelation >= ``period_correlation``),
   the level at each sample rises to the robust power at the same phase of the neighbouring
   periods (over ``period_guard``): an impulse repeats a period later, a defect does not.
   With ``impulses`` (off: it loses on the benchmark's windows, ``docs/nuisance-glr.md``), the
   train itself is fitted first (:mod:`railwatch.scoring.impulses`), before the bursts, and
   taken out; the harmonic model is then fitted again to the series less the train.
5. **Test**: the oracle's GLR scan for a spike and for boxes of ``min_box``-``max_box``
   samples on that whitened residual, each family calibrated to ``−log10`` of its family-wise
   p-value under N(0, 1) noise (:mod:`railwatch.scoring.glr`).
6. **Channels made comparable** by training statistics, as the matched filter's: per channel,
   the median and MAD-scale of the window maxima over the training windows (labels unused).

The doc page gives what each part recovers, and what is still lost at stages 7 and 8.

**At field scale** (a recording kept at its own rate; :meth:`NuisanceGLR.field_scale`) the
vehicle's response to the rail is broadband and coloured, not one sinusoid, and a squat is
itself a short ringing: a robust linear predictor (``order``, the matched filter's) whitens what
the harmonic model leaves and the spike and box tests are matched to its shapes; the energy
family, one noise scale per window, no speed jump inside a window, no bursts, no synchronous
level and no edge guard (``docs/nuisance-glr.md``, "At field scale").

**Windows in a stream** (``detect``: 2-s windows every 0.5 s, each sample's score the maximum
over the windows that hold it): a burst that starts in a window's last samples is, in that
window, a spike or a short box that no oscillation atom can be told apart from, and it wins the
maximum though the windows that hold it whole take it out. ``edge_guard`` leaves each window's
first and last steps to the windows that overlap them (:attr:`Detector.edge_guard`; the
recording's first and last samples keep the only window they have).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import median_filter
from threadpoolctl import threadpool_limits

from railwatch.detectors.api import (
    Detector,
    DetectorConfig,
    FloatArray,
    Scores,
    peak_standardized,
    peak_statistics,
)
from railwatch.detectors.matched_filter import (
    CHUNK_BYTES,
    MatchedFilter,
    error_filter,
    filter_correlate,
    prediction_error,
    robust_ar,
    template_norms,
)
from railwatch.errors import RailwatchError
from railwatch.recordings.floor import NOISE_FLOOR
from railwatch.scoring.bursts import best_burst
from railwatch.scoring.glr import (
    Family,
    effective_counts,
    effective_energy_count,
    families,
    raise_to_energy,
    scale_counts,
    scan,
)
from railwatch.scoring.harmonic import harmonic_fit
from railwatch.scoring.impulses import Train, fit_train
from railwatch.scoring.periodic import synchronous_level
from railwatch.scoring.residual import MAD_TO_STD, changepoint_scale

#: Series fitted at once: bounds the design matrices (series, T, 10) to a few MB.
CHUNK_SERIES = 512
#: Threads that fit chunks at once, at most one per core the process may use (one under
#: `taskset -c 0`, as the speed benchmarks pin `detect`).
MAX_THREADS = 2


@dataclass(frozen=True)
class NuisanceGLRConfig(DetectorConfig):
    harmonic: bool = True  # fit the harmonic model (step 1); off: the predictor alone
    poly: int = 2  # degree of the harmonic's amplitude polynomials (2: drift and curvature)
    chirp: bool = True  # the harmonic's frequency changes linearly across the window
    overtones: int = 2  # the fundamental's 2nd .. (1 + this)th harmonics, where a test keeps them
    change: float = 0.1  # a two-sided model where it lowers the residual's rms by this share
    huber_k: float = 1.345  # Huber threshold in robust standard deviations (95 % efficiency)
    irls_iterations: int = 3  # reweighting passes after the first least-squares fit
    min_cycles: float = 0.5  # spectral peaks under this many cycles per window are ignored
    order: int = 0  # taps of a robust linear predictor whitening what the harmonic left (0:
    # none, the benchmark's white noise; field scale: the track's coloured response, 8 ms)
    ridge: float = 0.1  # ... its relative ridge (the matched filter's)
    change_point: bool = True  # without a floor, the level changes once per window (stage 4)
    energy_boxes: tuple[int, ...] = ()  # lengths of the energy family (none: off; field scale)
    floor_span: int = 10  # the noise floor's running median: ±samples (0.1 s at 100 Hz)
    floor_weights: bool = True  # with a floor, the harmonic fitted to the series over its shape
    min_box: int = 5  # shortest local deviation, samples (spec: 0.05 s at 100 Hz)
    max_box: int = 20  # longest local deviation, samples (spec: 0.2 s at 100 Hz)
    bursts: bool = True  # take out a short oscillation better explained so than as a defect
    burst_margin: float = 12.0  # ... by this much more energy (noise variances) than a defect
    burst_ratio: float = 0.5  # ... and (1 + this) times its energy (a large defect's shape)
    burst_minimum: float = 20.0  # ... and this much in all
    burst_oversample: float = 4.0  # atom frequencies per 1 / length (the resolution)
    burst_max_length: int = 20  # the longest burst, samples (0.2 s at 100 Hz, as a defect's;
    # 30: 4 points more at stage 7 on recordings for 1.8 times the scoring time, notes 2026-12-07)
    burst_count: int = 2  # bursts taken out per window and channel, at most
    impulses: bool = False  # fit the wheel's impulse train and take it out (off: it loses; doc)
    impulse_correlation: float = 0.3  # ... where the residual's autocorrelation reaches this
    min_width: float = 0.7  # ... impulses this many samples wide at least (one-sided Gaussian
    max_width: float = 11.0  # ... ω; spec: 0.01-0.1 s at 100 Hz) and at most
    impulse_cap: float = 3.0  # ... each at most this many times the train's median amplitude
    impulse_minimum: float = 1.0  # ... where it explains this much per period (noise variances)
    period_guard: float = 1.25  # impulses: level >= the same phase's, over this (0: off)
    period_correlation: float = 0.2  # ... where the residual's autocorrelation reaches this
    min_period: int = 10  # the impulses' period, samples (0.1-0.5 s at 100 Hz: a wheel
    max_period: int = 50  # revolution at the benchmark's scale)
    edge_guard: int = 20  # detect: each window's first and last steps left to the windows
    # that overlap them (a burst or box cut by the window's edge is a shorter one; field scale 0)
    null_windows: int = 10000  # Monte Carlo N(0, 1) windows calibrating each family
    null_alpha: float = 0.05  # tail level at which each family's calibration is exact

    def __post_init__(self) -> None:
        try:  # lengths given as text (--set, a saved model's JSON) become numbers
            object.__setattr__(self, "energy_boxes", tuple(int(L) for L in self.energy_boxes))
        except (TypeError, ValueError):
            pass  # checked when the detector is used


def noise_level(residual: NDArray[np.float64], shape: NDArray[np.float64] | None,
                change: bool = True) -> NDArray[np.float64]:
    """The residual's noise std at every sample (B, T). Without a floor, a level with at most one
    change per series (``change``; its two sides' trimmed standard deviations are already the
    noise's size), or one robust scale (1.4826 MAD) per series. With a floor, its ``shape`` in
    time (:func:`floor_shape`, B × T) times the robust scale of the residual over that shape, one
    per series. ``residual / noise_level(...)`` is the whitened residual."""
    if shape is None and change:  # a second, window-wide scale on top only adds its own error
        return changepoint_scale(residual[:, :, None])[:, :, 0]
    level = np.ones_like(residual) if shape is None else shape
    u = residual / level
    return level * (MAD_TO_STD * np.median(np.abs(u), axis=1, keepdims=True) + 1e-12)


def floor_shape(floor: NDArray[np.float64], span: int) -> NDArray[np.float64]:
    """The noise's std at every sample up to a factor per series (B, T): √ of the floor's
    (B, T, power) running median over ±``span`` samples (a defect's edges do not raise it)."""
    level = np.sqrt(median_filter(np.maximum(floor, 0.0), size=(1, 2 * span + 1),
                                  mode="nearest"))
    return np.maximum(level, 1e-12 * (level.max(axis=1, keepdims=True) + 1e-300))


class NuisanceGLR(Detector):
    """Harmonic nuisance model + noise floor + the oracle's GLR scan (module docstring)."""

    Config: ClassVar[type[DetectorConfig]] = NuisanceGLRConfig
    config: NuisanceGLRConfig  # type: ignore[assignment]
    normalize: ClassVar[bool] = False  # the floor is in the recording's units
    fixed_length: ClassVar[bool] = False  # per-window fits; the calibration rescales to any T
    uses: ClassVar[tuple[str, ...]] = (NOISE_FLOOR,)

    @classmethod
    def field_scale(cls, fs: float) -> dict[str, Any]:
        """At field scale (a recording's own rate ``fs``): the matched filter's predictor, energy
        family and one noise scale per window (:meth:`MatchedFilter.field_scale`), a harmonic
        with no speed jump inside a window (no sinusoid of its own on each side) and no
        overtones (the predictor whitens them), no bursts, no synchronous level and no edge
        guard (module docstring, "At field scale")."""
        return {**MatchedFilter.field_scale(fs), "change": 0.0, "bursts": False,
                "impulses": False, "period_guard": 0.0, "overtones": 0, "edge_guard": 0}

    @property
    def edge_guard(self) -> int:
        """The ``edge_guard`` setting (module docstring, "Windows in a stream")."""
        return self.config.edge_guard

    def _families(self) -> tuple[Family, ...]:
        cfg = self.config
        if not 1 < cfg.min_box <= cfg.max_box:
            raise RailwatchError(
                f"need 1 < min_box <= max_box, got min_box={cfg.min_box}, max_box={cfg.max_box}")
        if cfg.order < 0 or not all(isinstance(L, int) and L >= 2 for L in cfg.energy_boxes):
            raise RailwatchError("order must be at least 0 and energy_boxes box lengths of at "
                                 f"least 2 samples, got order={cfg.order}, energy_boxes="
                                 f"{','.join(map(str, cfg.energy_boxes))}")
        if cfg.poly < 0 or cfg.floor_span < 0:
            raise RailwatchError(f"poly and floor_span must be at least 0, got poly={cfg.poly}, "
                                 f"floor_span={cfg.floor_span}")
        return families(cfg.min_box, cfg.max_box)

    def nuisance(self, x: NDArray[np.float64], shape: NDArray[np.float64] | None = None
                 ) -> NDArray[np.float64]:
        """Step 1: the harmonic model fitted to every series ``x`` (B, T); zeros without it.
        With a floor's ``shape`` (:func:`floor_shape`, B × T) and ``floor_weights``, fitted to
        the series over it: weighted least squares."""
        cfg = self.config
        if not cfg.harmonic:
            return np.zeros_like(x)
        return harmonic_fit(x, cfg.poly, cfg.huber_k, cfg.irls_iterations, cfg.min_cycles,
                            cfg.chirp, cfg.change, overtones=cfg.overtones,
                            level=shape if cfg.floor_weights else None)

    def impulse_train(self, w: NDArray[np.float64]) -> Train:
        """The wheel's impulse train in the whitened residual ``w`` (B, T), with this detector's
        settings (:func:`railwatch.scoring.impulses.fit_train`)."""
        cfg = self.config
        return fit_train(w, cfg.min_period, cfg.max_period, cfg.impulse_correlation,
                         cfg.min_width, cfg.max_width, cfg.impulse_minimum, cfg.impulse_cap)

    def whitened(self, r: NDArray[np.float64], shape: NDArray[np.float64] | None
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, NDArray[np.float64]]:
        """Steps 2-4 on the residual ``r`` (B, T) of every series (a copy is changed): with
        ``order``, the predictor's prediction error and its error filter (B, order + 1) that the
        tests are matched to (else None); then divided by the noise level, with the bursts and
        the impulse train taken out and the level raised where the same phase repeats. Returns
        the whitened residual, the error filter and the impulse train taken out (B, T), in
        ``r``'s units. ``shape``: the floor's (:func:`floor_shape`, B × T) or None."""
        cfg = self.config
        r, c = np.array(r, dtype=np.float64), None
        if cfg.order:  # what the harmonic left, whitened: the test matched to c * box
            coef = robust_ar(r, cfg.order, cfg.huber_k, cfg.irls_iterations, cfg.ridge)
            r, c = prediction_error(r, coef), error_filter(coef)
        level = noise_level(r, shape, cfg.change_point)

        def take_out(k: NDArray[np.bool_] | NDArray[np.intp], part: NDArray[np.float64]
                     ) -> None:
            """``part`` (in ``r``'s units) out of the series ``k``: it takes no part in their
            level either."""
            r[k] -= part
            level[k] = noise_level(r[k], None if shape is None else shape[k], cfg.change_point)

        impulses = np.zeros_like(r)
        if cfg.impulses:  # the wheel's impulse train, fitted and taken out
            train = self.impulse_train(r / level)
            k = train.kept
            if k.any():
                impulses[k] = train.fit[k] * level[k]
                take_out(k, impulses[k])
        atom_lengths = tuple(range(cfg.min_box, max(cfg.burst_max_length, cfg.min_box) + 1))
        # the strongest burst first; the next search looks only where one was taken out
        # (elsewhere it would find the same span, not kept, again)
        looked = np.arange(len(r))
        for _ in range(cfg.bursts * cfg.burst_count):
            burst = best_burst(r[looked] / level[looked], atom_lengths, cfg.burst_oversample,
                               cfg.burst_margin, cfg.burst_minimum, cfg.burst_ratio,
                               self._families()[1])
            looked = looked[burst.kept]
            if not len(looked):
                break
            take_out(looked, burst.fit[burst.kept] * level[looked])
        if cfg.period_guard > 0:  # the level rises where the same phase rises every period
            level = level * synchronous_level(r / level, cfg.min_period, cfg.max_period,
                                              cfg.period_guard, cfg.period_correlation)
        return r / level, c, impulses

    def residual(self, x: NDArray[np.float64], floor: NDArray[np.float64] | None
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """Steps 1-4 on every series ``x`` (B, T): the whitened residual and the error filter
        (:meth:`whitened`). Where an impulse train is taken out, the harmonic model is fitted
        again to the series less the train (a train pulls the harmonic's frequency and
        amplitudes, and the fit leaves part of every impulse), and the residual whitened
        again. ``floor``: (B, T, power) or None."""
        shape = None if floor is None else floor_shape(floor, self.config.floor_span)
        w, c, impulses = self.whitened(x - self.nuisance(x, shape), shape)
        if not (self.config.impulses and self.config.harmonic):
            return w, c
        k = np.flatnonzero(impulses.any(axis=1))
        if len(k):
            part = None if shape is None else shape[k]
            again = x[k] - self.nuisance(x[k] - impulses[k], part)
            w[k], ck, _ = self.whitened(again, part)
            if c is not None and ck is not None:
                c[k] = ck
        return w, c

    def raw_scores(self, X: FloatArray, floor: FloatArray | None = None) -> NDArray[np.floating]:
        """Unstandardised channel scores (N, T, C): calibrated −log10 family-wise p; ``floor``
        (N, T, C): the noise floor of each sample, if known."""
        cfg = self.config
        n, n_steps, n_channels = X.shape
        if n_steps < max(4 * (cfg.poly + 2), 2 * cfg.order + 2):
            raise RailwatchError(f"windows of {n_steps} steps are too short for the harmonic "
                                 f"model of degree {cfg.poly} and a predictor of order "
                                 f"{cfg.order}: need {max(4 * (cfg.poly + 2), 2 * cfg.order + 2)}")
        fams = self._families()
        counts = scale_counts(self.stats_["null_counts"], fams, self.n_steps_, n_steps)
        norms = [[np.sqrt(L) for L in fam] for fam in fams]  # a box of L white samples: √L
        out = np.empty((n, n_steps, n_channels))

        def scored(i: int) -> None:  # windows i .. i + step: fitted, whitened, scanned
            part = slice(i, i + step)

            def series(a: FloatArray) -> NDArray[np.float64]:
                return a[part].transpose(0, 2, 1).reshape(-1, n_steps).astype(np.float64)

            x = series(X)
            w, c = self.residual(x, None if floor is None else series(floor))
            ntc = (-1, n_channels, n_steps)
            if c is not None:  # the predictor's shapes (order > 0)
                g = filter_correlate(w, c).reshape(ntc).transpose(0, 2, 1)
                chunk_norms = [[v.reshape(-1, n_channels, 1).transpose(0, 2, 1)
                                for v in template_norms(c, fam)] for fam in fams]
                out[part] = scan(g, fams, chunk_norms, counts)
            else:
                out[part] = scan(w.reshape(ntc).transpose(0, 2, 1), fams, norms, counts)
            if cfg.energy_boxes:
                raise_to_energy(out[part], w.reshape(ntc).transpose(0, 2, 1), cfg.energy_boxes,
                                self.stats_["energy_count"], self.n_steps_)

        series_at_once = CHUNK_SERIES
        if cfg.order:  # the predictor's design matrices (series, 2 (T - p), p + 1) in cache
            per_series = 2 * (n_steps - cfg.order) * (cfg.order + 1) * 8
            series_at_once = min(series_at_once, CHUNK_BYTES // per_series)
        step = max(1, series_at_once // n_channels)
        starts = range(0, n, step)
        workers = min(len(starts), len(os.sched_getaffinity(0)), MAX_THREADS)
        if workers > 1:  # numpy lets go of the GIL in the fits: the cores it may use share them
            # one BLAS thread per worker: BLAS's own threads on top would contend for the cores
            with threadpool_limits(1, user_api="blas"), ThreadPoolExecutor(workers) as pool:
                list(pool.map(scored, starts))
        else:
            for i in starts:
                scored(i)
        return out

    def _fit(self, X: FloatArray, context: dict[str, FloatArray]) -> None:
        cfg = self.config
        self.stats_["null_counts"] = effective_counts(
            self.n_steps_, self._families(), cfg.null_windows, cfg.null_alpha, cfg.seed)
        if cfg.energy_boxes:
            self.stats_["energy_count"] = np.array([effective_energy_count(
                self.n_steps_, cfg.energy_boxes, cfg.null_windows, cfg.null_alpha, cfg.seed)])
        self.stats_.update(peak_statistics(self.raw_scores(X, context.get(NOISE_FLOOR))))

    def _score(self, X: FloatArray, context: dict[str, FloatArray], extras: bool) -> Scores:
        return peak_standardized(self.raw_scores(X, context.get(NOISE_FLOOR)), self.stats_)
