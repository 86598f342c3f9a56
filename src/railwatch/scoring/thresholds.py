"""Thresholds: rules that turn the instance scores of a detector's training windows into the one
number above which a window (or, on recordings, a sample) is flagged. A rule is a small frozen
object; ``rule.fit(scores)`` gives the threshold and ``rule.describe()`` names it in files.

The detector stores the fitted value once (``threshold`` in its fitted statistics, ``stats.npz``
in a model folder, the ONNX metadata in an export); a recordings model's ``recording.json``
names the rule that set it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray


class ThresholdRule(Protocol):
    def fit(self, scores: NDArray[Any]) -> float:
        """The threshold for these training instance scores."""
        ...

    def describe(self) -> str:
        """The rule and its setting, e.g. ``gumbel_null(tail=0.02)``."""
        ...


@dataclass(frozen=True)
class ContaminationQuantile:
    """The ``1 − contamination`` quantile of the training scores: flags the expected share of
    anomalous training windows (every detector's default, ``contamination`` in its config)."""

    contamination: float = 0.10

    def fit(self, scores: NDArray[Any]) -> float:
        return float(np.quantile(scores, 1.0 - self.contamination))

    def describe(self) -> str:
        return f"contamination_quantile(contamination={self.contamination:g})"


@dataclass(frozen=True)
class GumbelNull:
    """An event threshold that does not depend on how many training windows hold defects.

    A window's instance score is the maximum of many per-sample scores, so over normal windows it
    follows approximately a Gumbel distribution. Its location μ and scale β are fitted to the
    *lower half* of the training windows' scores (the quartile and the median), which defects,
    being high scores, leave alone as long as fewer than half the windows hold one; the threshold
    is the null's ``1 − tail`` quantile. On the synthesised 10-minute runs (one defect per 10 s,
    a fifth of the windows) the contamination quantile (0.10) put the threshold among the
    defects (attention model: 47 % found, no false events); this rule: 83 %, 0.4 false per
    minute (docs/recordings.md). ``train --recordings`` fits it with ``tail`` 0.02.

    >>> rng = np.random.default_rng(0)
    >>> null = rng.gumbel(0.0, 1.0, 100_000)
    >>> round(GumbelNull(0.02).fit(null), 1), round(float(np.quantile(null, 0.98)), 1)
    (3.9, 3.9)
    """

    tail: float = 0.02

    def fit(self, scores: NDArray[Any]) -> float:
        q25, q50 = np.quantile(scores, [0.25, 0.5])
        g25, g50 = -np.log(-np.log(0.25)), -np.log(-np.log(0.5))  # standard Gumbel quantiles
        beta = max(float(q50 - q25) / (g50 - g25), 1e-12)
        mu = float(q50) - beta * g50
        return float(mu - beta * np.log(-np.log(1.0 - self.tail)))

    def describe(self) -> str:
        return f"gumbel_null(tail={self.tail:g})"
