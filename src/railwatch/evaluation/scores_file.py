"""The scores file that ``railwatch score`` writes and ``railwatch evaluate`` reads: one ``.npz``
with ``instance`` (n,), ``point`` (n, T), ``channel`` (n, T, C), the fitted ``threshold``, each
window's localised ``time_index`` and ``channel_index``, and the ``detector``'s registry name."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from railwatch.atomic import atomic_path, atomic_savez
from railwatch.detectors.api import Detector, Scores
from railwatch.errors import RailwatchError, one_line
from railwatch.evaluation.metrics import evaluate_scores
from railwatch.scoring.reduce import localize
from railwatch.windows import WindowSet

SCORE_KEYS = ("instance", "point", "channel", "threshold")


def write_scores(path: str | os.PathLike[str], detector: Detector, scores: Scores) -> Path:
    """Write ``scores`` of ``detector`` with their localisation, atomically."""
    loc = localize(scores.point, scores.channel, detector.config.fs)
    return atomic_savez(path, {
        "instance": scores.instance, "point": scores.point, "channel": scores.channel,
        "threshold": np.array(detector.threshold_), "time_index": loc.time_index,
        "channel_index": loc.channel, "detector": np.array(detector.registry_name),
    })


def read_scores(path: str | os.PathLike[str]) -> tuple[Scores, float]:
    """The scores and fitted threshold of a scores file, with one-line errors."""
    path = Path(path)
    if not path.is_file():
        raise RailwatchError(f"no such file: {path}")
    try:
        with np.load(path, allow_pickle=False) as f:
            missing = [k for k in SCORE_KEYS if k not in f.files]
            if missing:
                raise RailwatchError(f"{path} lacks {', '.join(missing)}: is it a scores file "
                                     "from 'railwatch score'?")
            arrays = {k: f[k] for k in SCORE_KEYS}
    except RailwatchError:
        raise
    except Exception as e:  # noqa: BLE001
        raise RailwatchError(f"cannot read {path}: {one_line(e)[:160]}") from None
    scores = Scores(instance=arrays["instance"], point=arrays["point"], channel=arrays["channel"])
    return scores, float(arrays["threshold"])


def evaluate_files(data: str | os.PathLike[str],
                   scores_path: str | os.PathLike[str]) -> tuple[WindowSet, dict[str, float]]:
    """The metrics of a labelled window file's scores file: (the windows, metric -> value)."""
    windows = WindowSet.load(data)
    windows.require_labels(data)
    assert windows.y is not None and windows.mask is not None and windows.channel is not None
    scores, threshold = read_scores(scores_path)
    if scores.channel.shape != windows.X.shape:
        raise RailwatchError(f"scores have shape {scores.channel.shape} but the data "
                             f"{windows.X.shape}: were they computed on {data}?")
    metrics = evaluate_scores(windows.y, windows.mask, windows.channel, scores, threshold,
                              fs=float(windows.meta.get("fs", 100.0)))
    return windows, metrics


def write_metrics(path: str | os.PathLike[str], metrics: dict[str, float]) -> Path:
    """The metrics as JSON (NaN as null), atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(
            {k: (None if math.isnan(v) else v) for k, v in metrics.items()}, indent=2))
    return Path(path)
