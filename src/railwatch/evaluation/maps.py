"""Scoring a track map against the truth: the true defects as stretches of track, and the
recall and false places of a map's places (``railwatch track-map --truth``, the benchmarks)."""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from railwatch.errors import RailwatchError
from railwatch.evaluation.crossings import score_places


class Place(Protocol):
    """What scoring reads of a map's place (``railwatch.trackmap.folder.Location``)."""

    @property
    def position_m(self) -> float: ...


def read_truth(path: str | os.PathLike[str]) -> NDArray[np.float64]:
    """True defects as stretches of track, (n, 2) start and end in m: a ``position_m`` column
    (where each starts) and, if there is one, ``length_m`` (a track's defects table)."""
    path = Path(path)
    try:
        with open(path, newline="") as fh:
            reader = csv.DictReader(fh)
            if "position_m" not in (reader.fieldnames or []):
                raise RailwatchError(f"{path} needs a position_m column of defect positions")
            rows = list(reader)
        start = np.array([float(r["position_m"]) for r in rows], dtype=float)
        length = np.array([float(r.get("length_m") or 0.0) for r in rows], dtype=float)
    except OSError as e:
        raise RailwatchError(f"cannot read {path}: {e}") from None
    except ValueError:
        raise RailwatchError(f"{path}: position_m and length_m must hold numbers of metres") \
            from None
    return np.stack([start, start + length], axis=1).reshape(-1, 2)


def on_stretch(truth: NDArray[np.float64], lo: float, hi: float) -> NDArray[np.float64]:
    """The true defects (:func:`read_truth`) that lie on the stretch ``[lo, hi]``."""
    truth = np.asarray(truth, dtype=float).reshape(-1, 2)
    return truth[(truth[:, 1] >= lo) & (truth[:, 0] <= hi)]


def score_locations(locations: Sequence[Place], truth: NDArray[np.float64], length_m: float,
                    tolerance_m: float = 2.0,
                    features: NDArray[np.float64] | None = None) -> dict[str, float]:
    """Recall of the true defects (stretches ``(start, end)``, or positions) by ``locations``
    (a location within ``tolerance_m`` of a defect's stretch finds it), the locations near no
    true defect (nor, when given, a feature's stretch) per km of ``length_m``, the locations on
    features, the frame's offset and the recall with it taken out
    (:func:`railwatch.evaluation.crossings.score_places`)."""
    truth = np.asarray(truth, dtype=float)
    truth = np.stack([truth, truth], axis=1) if truth.ndim == 1 else truth.reshape(-1, 2)
    at = [loc.position_m for loc in locations]
    s = score_places(at, truth, features, length_m / 1000.0, tolerance_m)
    framed = score_places(at, truth, features, length_m / 1000.0, tolerance_m, remove_frame=True)
    return {"recall": float(s.found.mean()) if len(truth) else math.nan,
            "false_per_km": s.false_per_km, "locations": float(len(locations)),
            "on_features": float(s.on_features), "frame_offset_m": s.frame_offset_m,
            "recall_frame": float(framed.found.mean()) if len(truth) else math.nan}


def against_truth(reported: Sequence[Place], truth: NDArray[np.float64],
                  path: str | os.PathLike[str], lo: float, hi: float,
                  tolerance_m: float = 2.0) -> str:
    """``track-map --truth``, in words: the recall of the true defects ``truth`` (read from
    ``path`` by :func:`read_truth`) on the covered stretch ``[lo, hi]`` (m) by ``reported``
    within ``tolerance_m``, the false places per km (a ``track.features.csv`` beside the truth
    counts its features apart) and the frame's offset with the recall it hides."""
    path = Path(path)
    covered = on_stretch(truth, lo, hi)
    beside = path.with_name("track.features.csv")  # simulate's features: not defects
    features = read_truth(beside) if beside.is_file() and beside != path else None
    s = score_locations(reported, covered, hi - lo, tolerance_m, features)
    line = (f"against the {len(covered)} defects of {path.name} on the covered "
            f"{(hi - lo) / 1000:.1f} km: recall {s['recall']:.0%} within "
            f"±{tolerance_m:g} m, {s['false_per_km']:.2f} false locations per km")
    if features is not None:
        line += f" ({s['on_features']:.0f} more on the features of {beside.name})"
    if not math.isnan(s["frame_offset_m"]):
        line += (f"; the places sit {s['frame_offset_m']:+.1f} m from the defects in the "
                 f"median (the map's frame: odometry's common error), recall "
                 f"{s['recall_frame']:.0%} with it taken out")
    return line
