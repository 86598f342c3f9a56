"""Events and map places against the crossings and items of a physics track."""

from __future__ import annotations

import math

import numpy as np
import pytest

from railwatch.evaluation.crossings import score_events, score_places

DEFECTS = [{"defect": 0, "time_s": 10.0, "duration_s": 0.002, "speed_ms": 20.0},
           {"defect": 1, "time_s": 30.0, "duration_s": 0.05, "speed_ms": 10.0}]
FEATURES = [{"defect": 0, "time_s": 50.0, "duration_s": 0.02, "speed_ms": 20.0}]


def ev(start: float, end: float) -> dict[str, float]:
    return {"start_s": start, "end_s": end}


def test_events_find_defects_and_echoes_and_features_are_apart() -> None:
    events = [ev(9.98, 10.01),  # on defect 0
              ev(10.12, 10.14),  # the second wheelset, 2.56 m behind at 20 m/s: 0.128 s later
              ev(50.0, 50.01),  # on a feature
              ev(70.0, 70.1)]  # nothing
    s = score_events(events, DEFECTS, FEATURES, minutes=2.0, echo_offsets_m=(2.56, 19.0))
    assert s.found == {0: True, 1: False}
    assert (s.on_defects, s.explained, s.false) == (1, 2, 1)
    assert s.false_per_minute == 0.5
    # Without the wheelsets' offsets the echo is false.
    assert score_events(events, DEFECTS, FEATURES, 2.0).false == 2


def test_places_find_defects_apart_from_features_and_measure_the_frame() -> None:
    defects = np.array([[x, x + 0.05] for x in (100.0, 500.0, 900.0)])
    features = np.array([[700.0, 700.4]])
    # Every place 4 m past its item (a common odometry offset), and one place on nothing.
    places = [104.0, 504.05, 904.0, 704.2, 300.0]
    mapped = score_places(places, defects, features, km=1.0, tolerance_m=3.0)
    assert mapped.frame_offset_m == pytest.approx(4.0, abs=0.05)
    assert not mapped.found.any() and (mapped.on_features, mapped.false) == (0, 5)
    s = score_places(places, defects, features, km=1.0, tolerance_m=3.0, remove_frame=True)
    assert s.found.all() and s.offsets_m == pytest.approx([4.0, 4.0, 4.0], abs=0.05)
    assert (s.on_features, s.false, s.false_per_km) == (1, 1, 1.0)
    # A 3-m step 1 m ahead of its place once the frame is removed: the place, 4 m on, lies
    # inside the step's stretch as mapped, which is no reason to miss it.
    step = np.vstack([defects, [[1500.0, 1503.0]]])
    s = score_places([*places, 1503.0], step, features, km=1.0, remove_frame=True)
    assert s.found.all()
    empty = score_places([], defects, features, km=1.0)
    assert math.isnan(empty.frame_offset_m) and not empty.found.any()
