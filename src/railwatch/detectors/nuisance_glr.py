"""nuisance-glr: the GLR test of the oracle on a residual whose nuisance is modelled, not learned
(``docs/nuisance-glr.md``).

The oracle knows each window's nuisance signal and noise level and tests the whitened residual
for a spike or a box. This detector puts explicit estimates in their place, per window and
channel (vectorised over the N·C series, chunks of windows on up to two threads):

1. **Nuisance**: the harmonic model of :mod:`railwatch.scoring.harmonic`, a sinusoid at the
   window's spectral peak whose frequency changes linearly (``chirp``) and whose amplitude and
   phase drift as quadratics in time, plus an intercept and a trend, fitted by Huber-weighted
   least squares; where the frequency jumps at one instant (the paper's speed change), a
   sinusoid of its own on each side of the jump, found as the kink of the oscillation's phase,
   when that lowers the residual's rms by ``change``.
2. **Noise level**: where ``detect`` hands it the recording's noise floor
   (:mod:`railwatch.recordings.floor`: the level measured in the band that the resampling
   throws away), the residual is divided by its running median over ±``floor_span`` samples,
   so that the level may step anywhere in the window; without a floor, by a level with at most
   one change per window (:func:`railwatch.scoring.residual.changepoint_scale`, the paper's
   stage 4). Then by the robust scale (1.4826 MAD) of what is left, one per window.
3. **Test**: the oracle's GLR scan for a spike and for boxes of ``min_box``-``max_box``
   samples on that whitened residual, each family calibrated to ``−log10`` of its family-wise
   p-value under N(0, 1) noise (:mod:`railwatch.scoring.glr`).
4. **Channels made comparable** by training statistics, as the matched filter's: per channel,
   the median and MAD-scale of the window maxima over the training windows (labels unused).

What it does not model yet: bursts of rough track and the wheel's periodic impulses (stages 7
and 8). The doc page gives what each costs it.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import median_filter

from railwatch.detectors.api import (
    Detector,
    DetectorConfig,
    FloatArray,
    Scores,
    peak_standardized,
    peak_statistics,
)
from railwatch.errors import RailwatchError
from railwatch.recordings.floor import NOISE_FLOOR
from railwatch.scoring.glr import Family, effective_counts, families, scale_counts, scan
from railwatch.scoring.harmonic import MAD_TO_STD, harmonic_fit
from railwatch.scoring.residual import changepoint_scale

#: Series fitted at once: bounds the design matrices (series, T, 10) to a few MB.
CHUNK_SERIES = 512
#: Threads that fit chunks at once, at most one per core the process may use (one under
#: `taskset -c 0`, as the speed benchmarks pin `detect`).
MAX_THREADS = 2


@dataclass(frozen=True)
class NuisanceGLRConfig(DetectorConfig):
    poly: int = 2  # degree of the harmonic's amplitude polynomials (2: drift and curvature)
    chirp: bool = True  # the harmonic's frequency changes linearly across the window
    change: float = 0.1  # a two-sided model where it lowers the residual's rms by this share
    huber_k: float = 1.345  # Huber threshold in robust standard deviations (95 % efficiency)
    irls_iterations: int = 3  # reweighting passes after the first least-squares fit
    min_cycles: float = 0.5  # spectral peaks under this many cycles per window are ignored
    floor_span: int = 10  # the noise floor's running median: ±samples (0.1 s at 100 Hz)
    min_box: int = 5  # shortest local deviation, samples (spec: 0.05 s at 100 Hz)
    max_box: int = 20  # longest local deviation, samples (spec: 0.2 s at 100 Hz)
    null_windows: int = 10000  # Monte Carlo N(0, 1) windows calibrating each family
    null_alpha: float = 0.05  # tail level at which each family's calibration is exact


def whiten(residual: NDArray[np.float64], floor: NDArray[np.float64] | None,
           span: int) -> NDArray[np.float64]:
    """The residual (B, T) over its noise level: divided by √(running median of ``floor``,
    ±``span`` samples) where a floor (B, T, power) is given, then by the robust scale of what is
    left (one per series)."""
    if floor is None:
        u = residual / changepoint_scale(residual[:, :, None])[:, :, 0]
    else:
        level = np.sqrt(median_filter(np.maximum(floor, 0.0), size=(1, 2 * span + 1),
                                      mode="nearest"))
        u = residual / np.maximum(level, 1e-12 * (level.max(axis=1, keepdims=True) + 1e-300))
    return u / (MAD_TO_STD * np.median(np.abs(u), axis=1, keepdims=True) + 1e-12)


class NuisanceGLR(Detector):
    """Harmonic nuisance model + noise floor + the oracle's GLR scan (module docstring)."""

    Config: ClassVar[type[DetectorConfig]] = NuisanceGLRConfig
    config: NuisanceGLRConfig  # type: ignore[assignment]
    normalize: ClassVar[bool] = False  # the floor is in the recording's units
    fixed_length: ClassVar[bool] = False  # per-window fits; the calibration rescales to any T
    uses: ClassVar[tuple[str, ...]] = (NOISE_FLOOR,)

    def _families(self) -> tuple[Family, ...]:
        cfg = self.config
        if not 1 < cfg.min_box <= cfg.max_box:
            raise RailwatchError(
                f"need 1 < min_box <= max_box, got min_box={cfg.min_box}, max_box={cfg.max_box}")
        if cfg.poly < 0 or cfg.floor_span < 0:
            raise RailwatchError(f"poly and floor_span must be at least 0, got poly={cfg.poly}, "
                                 f"floor_span={cfg.floor_span}")
        return families(cfg.min_box, cfg.max_box)

    def raw_scores(self, X: FloatArray, floor: FloatArray | None = None) -> NDArray[np.floating]:
        """Unstandardised channel scores (N, T, C): calibrated −log10 family-wise p; ``floor``
        (N, T, C): the noise floor of each sample, if known."""
        cfg = self.config
        n, n_steps, n_channels = X.shape
        if n_steps < 4 * (cfg.poly + 2):
            raise RailwatchError(f"windows of {n_steps} steps are too short for the harmonic "
                                 f"model of degree {cfg.poly}: need {4 * (cfg.poly + 2)}")
        fams = self._families()
        counts = scale_counts(self.stats_["null_counts"], fams, self.n_steps_, n_steps)
        norms = [[np.sqrt(L) for L in fam] for fam in fams]  # a box of L white samples: √L
        out = np.empty((n, n_steps, n_channels))

        def scored(i: int) -> None:  # windows i .. i + step: fitted, whitened, scanned
            part = slice(i, i + step)

            def series(a: FloatArray) -> NDArray[np.float64]:
                return a[part].transpose(0, 2, 1).reshape(-1, n_steps).astype(np.float64)

            x = series(X)
            r = x - harmonic_fit(x, cfg.poly, cfg.huber_k, cfg.irls_iterations, cfg.min_cycles,
                                 cfg.chirp, cfg.change)
            w = whiten(r, None if floor is None else series(floor), cfg.floor_span)
            out[part] = scan(w.reshape(-1, n_channels, n_steps).transpose(0, 2, 1), fams, norms,
                             counts)

        step = max(1, CHUNK_SERIES // n_channels)
        starts = range(0, n, step)
        workers = min(len(starts), len(os.sched_getaffinity(0)), MAX_THREADS)
        if workers > 1:  # numpy lets go of the GIL in the fits: the cores it may use share them
            with ThreadPoolExecutor(workers) as pool:
                list(pool.map(scored, starts))
        else:
            for i in starts:
                scored(i)
        return out

    def _fit(self, X: FloatArray, context: dict[str, FloatArray]) -> None:
        cfg = self.config
        self.stats_["null_counts"] = effective_counts(
            self.n_steps_, self._families(), cfg.null_windows, cfg.null_alpha, cfg.seed)
        self.stats_.update(peak_statistics(self.raw_scores(X, context.get(NOISE_FLOOR))))

    def _score(self, X: FloatArray, context: dict[str, FloatArray], extras: bool) -> Scores:
        return peak_standardized(self.raw_scores(X, context.get(NOISE_FLOOR)), self.stats_)
