"""Probability of detection from hit/miss data, as inspection methods are qualified
(MIL-HDBK-1823A, "hit/miss" analysis).

Each defect (or each crossing of one) is a hit or a miss; its size ``a`` (a depth in mm) is
known. The POD curve is a logistic regression of the hits on ``log a``:

    POD(a) = 1 / (1 + exp(−(β₀ + β₁ · ln a)))

fitted by maximum likelihood (statsmodels' binomial GLM with the logit link). ``a50`` and
``a90`` are the sizes found with probability 0.5 and 0.9, ``ln a_p = (logit p − β₀) / β₁``;
``a90/95`` is the upper one-sided 95 % confidence bound on ``a90`` by the delta method on the
fit's covariance (the Wald bound of MIL-HDBK-1823A's hit/miss analysis):
``ln a90/95 = ln a90 + 1.645 · √(g Σ gᵀ)``, ``g = (−1/β₁, −ln a90/β₁)``.

Where the data do not allow a fit (no miss, no hit, fewer than ten points, sizes that separate
hits from misses exactly, or a curve that does not rise with size), :func:`fit_pod` says so
instead of a number: with every defect found, ``a90`` lies below the smallest size tried.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
Z95 = 1.6448536269514722  # one-sided 95 %


@dataclass(frozen=True)
class PodFit:
    """A hit/miss POD fit; ``note`` says why sizes are NaN when the data allow no fit."""

    n: int
    hits: int
    beta0: float
    beta1: float
    cov: tuple[tuple[float, float], tuple[float, float]]
    a50: float
    a90: float
    a90_95: float
    smallest: float  # the smallest and largest size tried
    largest: float
    note: str = ""

    def pod(self, a: FloatArray) -> FloatArray:
        """The fitted POD at sizes ``a``."""
        x = self.beta0 + self.beta1 * np.log(np.asarray(a, dtype=float))
        return np.asarray(1.0 / (1.0 + np.exp(-x)), dtype=float)

    def describe(self, unit: str = "mm") -> str:
        """a90 and a90/95 for a table cell."""
        if self.note:
            return self.note
        return f"{self.a90:.3g} / {self.a90_95:.3g} {unit}"


def _size_at(p: float, b0: float, b1: float) -> float:
    return (math.log(p / (1 - p)) - b0) / b1


def fit_pod(size: FloatArray, hit: NDArray[np.bool_] | FloatArray) -> PodFit:
    """The hit/miss POD curve of defects of ``size`` (> 0) that were found (``hit``)."""
    import statsmodels.api as sm
    from statsmodels.tools.sm_exceptions import PerfectSeparationWarning

    a = np.asarray(size, dtype=float)
    y = np.asarray(hit, dtype=float)
    if a.shape != y.shape or not (a > 0).all():
        raise ValueError("sizes must be positive and one per hit or miss")
    n, hits = len(a), int(y.sum())
    lo, hi = (float(a.min()), float(a.max())) if n else (math.nan, math.nan)
    nan2 = ((math.nan, math.nan), (math.nan, math.nan))

    def unfit(note: str) -> PodFit:
        return PodFit(n, hits, math.nan, math.nan, nan2, math.nan, math.nan, math.nan, lo, hi,
                      note)

    if n < 10:
        return unfit(f"{n} points: too few to fit")
    if hits == n:
        return unfit(f"all {n} found: a90 below {lo:.3g}")
    if hits == 0:
        return unfit(f"none of {n} found: a90 above {hi:.3g}")
    x = np.log(a)
    if x[y == 1].min() > x[y == 0].max():
        return unfit(f"hits and misses separate at {math.exp(x[y == 0].max()):.3g}-"
                     f"{math.exp(x[y == 1].min()):.3g}: no slope to fit")
    with warnings.catch_warnings():
        warnings.simplefilter("error", PerfectSeparationWarning)
        try:
            res = sm.GLM(y, sm.add_constant(x), family=sm.families.Binomial()).fit()
        except PerfectSeparationWarning:
            return unfit("hits and misses separate: no slope to fit")
    b0, b1 = (float(v) for v in res.params)
    cov = np.asarray(res.cov_params(), dtype=float)
    if not b1 > 0:
        return unfit("the fitted POD does not rise with size")
    l50, l90 = _size_at(0.5, b0, b1), _size_at(0.9, b0, b1)
    g = np.array([-1.0 / b1, -l90 / b1])
    se = float(np.sqrt(g @ cov @ g))
    return PodFit(n, hits, b0, b1, ((cov[0, 0], cov[0, 1]), (cov[1, 0], cov[1, 1])),
                  math.exp(l50), math.exp(l90), math.exp(l90 + Z95 * se), lo, hi)
