"""Events and map places against what a vehicle really crossed.

A recording's truth is a table of **crossings** (``passNN.defects.csv`` and ``.features.csv`` of
``railwatch simulate``): when the sensors reached each item (``time_s``), how long they took
to cross it (``duration_s``), at what speed (``speed_ms``). :func:`score_events` matches a
pass's events to them: an event finds a defect when it overlaps the sensors' crossing (within
``tol_s``). The coach's other wheelsets cross the same item later (by their distance behind
the sensors over the speed), and an item that is not a defect (a turnout, a transition)
answers too: such events are **explained**, counted apart from the defects found; the rest are
**false**.

:func:`score_places` does the same for a map's places along the track: a place within
``tolerance_m`` of a defect's stretch finds it, a place on a feature is counted apart. With
positions from odometry alone every pass, and so the map's frame, carries a common offset: the
places sit on one side of the defects. That offset is the frame's error, not a miss: it is
measured (the median of the signed distances of places to the defect they lie nearest, within
``frame_search_m``) and reported apart, and recall is given both as the map says and with the
frame's offset taken out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass
class EventScore:
    """A pass's events against its crossings."""

    found: dict[int, bool]  # defect index -> an event overlapped the sensors' crossing
    on_defects: int  # events that found a defect
    explained: int  # events on another wheelset's crossing of a defect, or on a feature
    false: int
    minutes: float

    @property
    def false_per_minute(self) -> float:
        return self.false / max(self.minutes, 1e-9)


def _overlaps(starts: FloatArray, ends: FloatArray, t0: float, t1: float, tol: float
              ) -> NDArray[np.bool_]:
    return (starts - tol <= t1) & (ends + tol >= t0)


def score_events(events: Sequence[dict[str, Any]], defects: Sequence[dict[str, Any]],
                 features: Sequence[dict[str, Any]], minutes: float,
                 echo_offsets_m: Sequence[float] = (), tol_s: float = 0.1) -> EventScore:
    """Match ``events`` (``start_s``, ``end_s``) to the crossings of ``defects`` and
    ``features`` (``defect``, ``time_s``, ``duration_s``, ``speed_ms``; module docstring).
    ``echo_offsets_m``: how far behind the sensors the coach's other wheelsets run."""
    starts = np.array([float(e["start_s"]) for e in events], dtype=float)
    ends = np.array([float(e["end_s"]) for e in events], dtype=float)
    hit = np.zeros(len(events), dtype=bool)
    explained = np.zeros(len(events), dtype=bool)
    found: dict[int, bool] = {}
    for rows, is_defect in ((defects, True), (features, False)):
        for r in rows:
            t0 = float(r["time_s"])
            t1 = t0 + float(r["duration_s"])
            m = _overlaps(starts, ends, t0, t1, tol_s)
            if is_defect:
                found[int(r["defect"])] = bool(m.any())
                hit |= m
            else:
                explained |= m
            v = float(r["speed_ms"])
            for off in echo_offsets_m:
                explained |= _overlaps(starts, ends, t0 + off / v, t1 + off / v, tol_s)
    explained &= ~hit
    return EventScore(found=found, on_defects=int(hit.sum()), explained=int(explained.sum()),
                      false=int((~hit & ~explained).sum()), minutes=minutes)


@dataclass
class PlaceScore:
    """A map's places against the stretches of the defects and features along the track."""

    found: NDArray[np.bool_]  # per defect: a place within tolerance
    on_features: int  # places on a feature, not on a defect
    false: int
    km: float
    frame_offset_m: float  # the places' common offset from the defects (NaN: none near one)
    offsets_m: list[float] = field(default_factory=list)  # each found defect's place - defect

    @property
    def false_per_km(self) -> float:
        return self.false / max(self.km, 1e-9)


def _signed(at: FloatArray, stretches: FloatArray) -> FloatArray:
    """(stretches, places): each place's signed distance from each stretch (0 inside)."""
    start, end = stretches[:, :1], stretches[:, 1:]
    return np.where(at[None] < start, at[None] - start,
                    np.where(at[None] > end, at[None] - end, 0.0))


def score_places(positions: Sequence[float] | FloatArray, defects: FloatArray,
                 features: FloatArray | None, km: float, tolerance_m: float = 3.0,
                 remove_frame: bool = False, frame_search_m: float = 20.0) -> PlaceScore:
    """Places (m along the track) against the defects' and features' stretches ((n, 2) start
    and end, m) of a track (module docstring): where the map put them, or with the frame's
    common offset removed (``remove_frame``)."""
    at = np.asarray(positions, dtype=float).reshape(-1)
    defects = np.asarray(defects, dtype=float).reshape(-1, 2)
    features = np.asarray(features if features is not None else np.zeros((0, 2)),
                          dtype=float).reshape(-1, 2)
    d_def, d_feat = _signed(at, defects), _signed(at, features)
    near = np.abs(d_def) <= frame_search_m
    nearest = np.take_along_axis(d_def, np.abs(d_def).argmin(axis=0)[None], axis=0)[0] \
        if len(d_def) else np.zeros(len(at))
    frame = float(np.median(nearest[near.any(axis=0)])) if near.any() else math.nan
    r_def, r_feat = d_def, d_feat
    if remove_frame and not math.isnan(frame):  # the places moved, then measured again (a
        # distance to a stretch is not the distance to where the place was less the shift)
        r_def, r_feat = _signed(at - frame, defects), _signed(at - frame, features)
    on_def = np.abs(r_def) <= tolerance_m  # (defects, places)
    matched = on_def.any(axis=0)
    on_feat = (np.abs(r_feat) <= tolerance_m).any(axis=0) & ~matched
    found = np.asarray(on_def.any(axis=1), dtype=bool)
    offsets = [float(row[hit][np.abs(row[hit]).argmin()])
               for row, hit in zip(d_def, on_def, strict=True) if hit.any()]
    return PlaceScore(found=found, on_features=int(on_feat.sum()),
                      false=int((~matched & ~on_feat).sum()), km=km, frame_offset_m=frame,
                      offsets_m=offsets)
