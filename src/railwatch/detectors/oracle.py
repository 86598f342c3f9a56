"""The oracle: the achievable ceiling of each synthetic stage (``docs/detectors.md``, "Reference
detectors: oracle and matched filter").

It is handed the generator's components (``generate(..., components=True)``): the nuisance signal
(everything but white noise and the anomaly) and the per-sample noise std. Its whitened residual

    r = (X − nuisance) / noise_std          (N, T, C), i.i.d. N(0, 1) wherever there is no anomaly

carries only noise and the anomaly, so a generalised likelihood-ratio (GLR) test for the
benchmark's two anomaly kinds (``docs/benchmark.md``, "Anomalies") is optimal up to the unknown
amplitude, sign, position and length:

- spike at ``t``: ``|r_t|``;
- constant box of ``L`` = 5..20 samples at ``s``: ``|Σ_{s ≤ t < s+L} r_t| / √L``.

The two families (spike; boxes of all lengths) are calibrated by their own null distributions
(:mod:`railwatch.scoring.glr`): a statistic becomes ``−log10`` of its family-wise p-value under
N(0, 1) noise, with the family's effective number of tests fitted by Monte Carlo in
:meth:`Oracle.fit` (the only thing it "learns"; the data are not used). On stage-1 test data this
calibration gives instance ROC-AUC 0.998 against 0.997 for the plain maximum of all ``z``.
Channel score (N, T, C) = the largest calibrated statistic over the hypotheses covering (t, c);
point = max over channels; instance = max over time.

Uses: synthetic data only. Works for any window length (``fixed_length = False``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from railwatch.detectors.api import Detector, DetectorConfig, FloatArray, Scores
from railwatch.errors import RailwatchError
from railwatch.scoring.glr import Family, effective_counts, families, scale_counts, scan
from railwatch.scoring.reduce import reduce_instance_max, reduce_point_max


@dataclass(frozen=True)
class OracleConfig(DetectorConfig):
    min_box: int = 5  # shortest local deviation, samples (spec: 0.05 s at 100 Hz)
    max_box: int = 20  # longest local deviation, samples (spec: 0.2 s at 100 Hz)
    null_windows: int = 10000  # Monte Carlo N(0, 1) windows calibrating each family
    null_alpha: float = 0.05  # tail level at which each family's calibration is exact


def whitened_residual(
    X: FloatArray, nuisance: FloatArray, noise_std: FloatArray
) -> NDArray[np.float64]:
    """``(X − nuisance) / noise_std`` (N, T, C); raises if a noise std is not positive."""
    if not (noise_std > 0).all():
        w, t, c = np.argwhere(~(noise_std > 0))[0]
        raise RailwatchError(
            f"noise_std must be positive, got {noise_std[w, t, c]} at window {w}, step {t}, "
            f"channel {c}: pass the generator's per-sample noise std"
        )
    if nuisance.shape != X.shape or noise_std.shape != X.shape:
        raise RailwatchError(
            f"nuisance {nuisance.shape} and noise_std {noise_std.shape} must have the windows' "
            f"shape {X.shape}"
        )
    return (X.astype(np.float64) - nuisance) / noise_std


class Oracle(Detector):
    """GLR test on the residual whitened with the true nuisance signal and noise std."""

    Config: ClassVar[type[DetectorConfig]] = OracleConfig
    config: OracleConfig  # type: ignore[assignment]
    normalize: ClassVar[bool] = False  # the components are in the raw units of X
    fixed_length: ClassVar[bool] = False  # the calibration is rescaled to any window length
    needs: ClassVar[tuple[str, ...]] = ("nuisance", "noise_std")

    def _families(self) -> tuple[Family, ...]:
        cfg = self.config
        if not 1 < cfg.min_box <= cfg.max_box:
            raise RailwatchError(
                f"need 1 < min_box <= max_box, got min_box={cfg.min_box}, max_box={cfg.max_box}"
            )
        return families(cfg.min_box, cfg.max_box)

    def _fit(self, X: FloatArray, context: dict[str, FloatArray]) -> None:
        cfg = self.config
        # the families' null calibration; the data themselves teach an oracle nothing
        self.stats_["null_counts"] = effective_counts(
            self.n_steps_, self._families(), cfg.null_windows, cfg.null_alpha, cfg.seed)

    def _score(self, X: FloatArray, context: dict[str, FloatArray], extras: bool) -> Scores:
        r = whitened_residual(X, context["nuisance"], context["noise_std"])  # (N, T, C)
        fams = self._families()
        counts = scale_counts(self.stats_["null_counts"], fams, self.n_steps_, X.shape[1])
        norms = [[np.sqrt(L) for L in fam] for fam in fams]  # a box of L white samples: √L
        channel = scan(r, fams, norms, counts).astype(np.float32)
        point = reduce_point_max(channel)
        return Scores(instance=reduce_instance_max(point), point=point, channel=channel)
