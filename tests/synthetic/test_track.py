"""One track, many passes: defects fixed by position, each pass its own run and odometry."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from railwatch.errors import RailwatchError
from railwatch.synthetic.track import (
    MIN_GAP_M,
    TRACK_FIELDS,
    Odometry,
    make_track,
    synthesize_pass,
    write_track,
)


def test_a_track_is_fixed_by_its_seed() -> None:
    track = make_track(3000, 12, seed=4, stage=6)
    again = make_track(3000, 12, seed=4, stage=6)
    assert track.defects == again.defects and len(track.defects) == 12
    x = np.array([d.position_m for d in track.defects])
    assert (np.diff(x) >= MIN_GAP_M - 1e-3).all() and x[0] >= MIN_GAP_M
    assert x[-1] <= 3000 - MIN_GAP_M
    assert sum(d.kind == "spike" for d in track.defects) == 6
    assert all(d.length_m == 0 for d in track.defects if d.kind == "spike")
    assert all(1.1 <= d.length_m <= 4.5 for d in track.defects if d.kind == "deviation")
    with pytest.raises(RailwatchError, match="do not fit"):
        make_track(500, 40)


@pytest.mark.parametrize(("direction", "push_pull"), [(1, False), (-1, False), (-1, True)])
def test_a_pass_feels_every_defect_where_it_is(direction: int, push_pull: bool) -> None:
    track = make_track(2000, 8, seed=1)
    p = synthesize_pass(track, seed=3, fs=500.0, direction=direction,
                        odometry=Odometry(0.0, 0.0, 0.0), push_pull=push_pull)
    lo, hi = sorted((p.true_position[0], p.true_position[-1]))
    inside = [d for d in track.defects if lo <= d.position_m <= hi]
    assert {c["defect"] for c in p.crossings} == {d.defect for d in inside}
    assert np.all(np.diff([c["time_s"] for c in p.crossings]) > 0)
    assert np.sign(p.true_position[-1] - p.true_position[0]) == direction
    for c in p.crossings:  # where the pass was when it felt the defect, and on which side
        d = track.defects[c["defect"]]
        at = np.interp(c["time_s"], p.run.time, p.true_position)
        assert abs(at - d.position_m) < 0.1 or abs(at - d.position_m - d.length_m) < 0.1
        side = d.side if direction == 1 or push_pull else 3 - d.side  # a turned vehicle
        assert c["channel"] == f"{d.group}_{side}"
        if direction == -1 and not push_pull:  # the same defect, felt on the other channel
            assert c["channel"] != f"{d.group}_{d.side}"
        np.testing.assert_allclose(c["recorded_m"], np.interp(c["center_s"], p.run.time,
                                                              p.true_position), atol=0.2)


def test_odometry_errs_as_asked() -> None:
    track = make_track(4000, 4, seed=2)
    exact = synthesize_pass(track, seed=5, fs=200.0, odometry=Odometry(0.0, 0.0, 0.0))
    np.testing.assert_allclose(exact.run.position, exact.true_position, atol=1e-6)
    errs = [synthesize_pass(track, seed=s, fs=200.0, odometry=Odometry(3.0, 0.001, 0.0))
            for s in range(6)]
    start_errors = [p.run.position[0] - p.true_position[0] for p in errs]
    assert 0.5 < np.std(start_errors) < 8
    rel = synthesize_pass(track, seed=5, fs=200.0, direction=-1,
                          odometry=Odometry(0.0, 0.0, 0.0, relative=True))
    np.testing.assert_allclose(rel.run.position, rel.true_position[0] - rel.true_position,
                               atol=1e-6)


def test_write_track(tmp_path: Path) -> None:
    track, paths = write_track(tmp_path / "t", 3, length_m=1500, n_defects=5, seed=1, fs=200.0,
                               suffix=".csv")
    assert [p.name for p in paths] == ["pass01.csv", "pass02.csv", "pass03.csv"]
    with open(tmp_path / "t" / "track.defects.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == TRACK_FIELDS and len(rows) == 5
    assert (tmp_path / "t" / "layout.toml").is_file()
    assert (tmp_path / "t" / "pass02.defects.csv").is_file()
    with pytest.raises(RailwatchError, match="--format"):
        write_track(tmp_path / "u", 1, suffix=".xlsx")
