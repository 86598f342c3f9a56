"""The metrics of ``docs/evaluation.md``, one named function each. No point adjustment anywhere.

Labels come from the generator (``y``, ``mask``, ``channel``); scores from a detector. Nothing here
chooses a threshold on the test set: ``f1_fitted`` takes predictions made with the threshold the
detector fitted on its training data.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sklearn.metrics import average_precision_score, f1_score, roc_auc_score

from railwatch.scoring.reduce import localize

log = logging.getLogger(__name__)

#: The paper's Table I footnote: thresholds at the top {0.5, 1, 1.5, 2, 10, 20, 30} % of scores.
PAPER_FRACTIONS = (0.005, 0.01, 0.015, 0.02, 0.10, 0.20, 0.30)
#: ``loc_time`` counts a hit inside the true span widened by this many samples on each side.
LOC_TOLERANCE = 2


def _both_classes(y: NDArray[Any], name: str) -> bool:
    if np.unique(y).size < 2:
        log.warning("%s is undefined: the labels hold a single class", name)
        return False
    return True


def auc_instance(y: NDArray[Any], instance: NDArray[Any]) -> float:
    """ROC-AUC of instance scores (N,) against instance labels (N,). The primary metric."""
    if not _both_classes(y, "auc_instance"):
        return math.nan
    return float(roc_auc_score(y, instance))


def auc_point(mask: NDArray[np.bool_], point: NDArray[Any]) -> float:
    """ROC-AUC of point scores (N, T) against "any channel anomalous at this step" (N·T values)."""
    labels = mask.any(axis=2).ravel()
    if not _both_classes(labels, "auc_point"):
        return math.nan
    return float(roc_auc_score(labels, np.asarray(point).ravel()))


def paper7_roc(
    y: NDArray[Any], instance: NDArray[Any], fractions: tuple[float, ...] = PAPER_FRACTIONS
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The paper's coarse ROC: (FPR, TPR) when flagging the top ``q`` of instance scores for each
    fraction q, plus (0, 0) and (1, 1), sorted by FPR.

    Flagging the top q means the ``ceil(q·N)`` highest scores (ties at the cut are flagged too).
    """
    y = np.asarray(y).astype(bool)
    s = np.asarray(instance, dtype=np.float64)
    ranked = np.sort(s)[::-1]
    fpr, tpr = [0.0, 1.0], [0.0, 1.0]
    for q in fractions:
        k = max(1, math.ceil(q * len(s) - 1e-9))
        flagged = s >= ranked[k - 1]
        tpr.append(float((flagged & y).sum() / y.sum()))
        fpr.append(float((flagged & ~y).sum() / (~y).sum()))
    order = np.lexsort((tpr, fpr))
    return np.asarray(fpr)[order], np.asarray(tpr)[order]


def auc_paper7(y: NDArray[Any], instance: NDArray[Any]) -> float:
    """Trapezoid area under :func:`paper7_roc` (the paper's Table I footnote)."""
    if not _both_classes(y, "auc_paper7"):
        return math.nan
    fpr, tpr = paper7_roc(y, instance)
    return float(np.sum(np.diff(fpr) * (tpr[1:] + tpr[:-1]) / 2))


def ap_instance(y: NDArray[Any], instance: NDArray[Any]) -> float:
    """Average precision (PR-AUC) of instance scores."""
    if not _both_classes(y, "ap_instance"):
        return math.nan
    return float(average_precision_score(y, instance))


def f1_fitted(y: NDArray[Any], predicted: NDArray[Any]) -> float:
    """Instance F1 of predictions made with the threshold fitted on training scores."""
    return float(f1_score(y, predicted, zero_division=0.0))


def loc_time(
    mask: NDArray[np.bool_], time_index: NDArray[Any], tolerance: int = LOC_TOLERANCE
) -> float:
    """Over anomalous windows: the fraction whose localised time step lies inside the true span
    widened by ``tolerance`` samples on each side."""
    steps = np.asarray(mask, dtype=bool).max(axis=2)  # (N, T): any channel anomalous
    anomalous = np.flatnonzero(steps.any(axis=1))
    if anomalous.size == 0:
        return math.nan
    s = steps[anomalous]
    first = s.argmax(axis=1)
    last = s.shape[1] - 1 - s[:, ::-1].argmax(axis=1)
    t = np.asarray(time_index)[anomalous]
    return float(np.mean((t >= first - tolerance) & (t <= last + tolerance)))


def loc_channel(
    true_channel: NDArray[Any], channel: NDArray[Any], n_channels: int
) -> float:
    """Over anomalous windows of multi-channel data: the fraction whose localised channel is the
    anomalous one. NaN for single-channel data, where it means nothing."""
    anomalous = np.asarray(true_channel) >= 0
    if n_channels < 2 or not anomalous.any():
        return math.nan
    return float(np.mean(np.asarray(channel)[anomalous] == np.asarray(true_channel)[anomalous]))


def timed(fn: Callable[[], Any], repeats: int = 3) -> tuple[float, Any]:
    """Median wall seconds of ``fn()`` over ``repeats`` runs, and what the last run returned."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times)), result


def score_seconds(detector: Any, X: NDArray[Any], context: Any = None, repeats: int = 3) -> float:
    """``score_s``: wall seconds to score all of ``X`` at the detector's batch size (32 by
    default) after a warm-up batch, median of ``repeats``."""
    return timed_scores(detector, X, context, repeats)[0]


def timed_scores(detector: Any, X: NDArray[Any], context: Any = None,
                 repeats: int = 3) -> tuple[float, Any]:
    """:func:`score_seconds` and the scores of ``X`` it computed (scoring is deterministic, so
    a benchmark cell scores its test set once, timed)."""
    batch = detector.config.batch_size
    warm_ctx = {k: v[:batch] for k, v in context.items()} if context else None
    detector.score(X[:batch], warm_ctx)
    return timed(lambda: detector.score(X, context), repeats)


def evaluate_scores(
    y: NDArray[Any],
    mask: NDArray[np.bool_],
    true_channel: NDArray[Any],
    scores: Any,
    threshold: float,
    fs: float = 100.0,
) -> dict[str, float]:
    """Every quality metric of the spec for one scored test set.

    ``scores`` is a :class:`railwatch.detectors.Scores` (or anything with ``instance``, ``point``
    and ``channel``); ``threshold`` the detector's fitted ``threshold_``.
    """
    loc = localize(scores.point, scores.channel, fs)
    return {
        "auc_instance": auc_instance(y, scores.instance),
        "auc_point": auc_point(mask, scores.point),
        "auc_paper7": auc_paper7(y, scores.instance),
        "ap_instance": ap_instance(y, scores.instance),
        "f1_fitted": f1_fitted(y, (scores.instance > threshold).astype(np.int8)),
        "loc_time": loc_time(mask, loc.time_index),
        "loc_channel": loc_channel(true_channel, loc.channel, mask.shape[2]),
    }
