"""A synthesised run written as a recording, its layout and its true defects."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from railwatch.errors import RailwatchError
from railwatch.recordings.layout import load_layout
from railwatch.recordings.readers import Recording
from railwatch.synthetic.run_files import check_run_settings, write_run
from railwatch.synthetic.runs import DEFECT_FIELDS


def test_write_run_writes_a_readable_recording(tmp_path: Path) -> None:
    out = tmp_path / "run.csv"
    run, layout_path, truth_path = write_run(out, 0.5, seed=3, fs=200.0, every_s=5.0)
    assert (layout_path, truth_path) == (tmp_path / "run.layout.toml", tmp_path / "run.defects.csv")
    rec = Recording(out, load_layout(layout_path))
    assert abs(rec.duration_s - 30.0) < 0.01
    data = np.concatenate([c.data for c in rec.chunks()])
    np.testing.assert_allclose(data[:, 0], run.columns()[rec.layout.channels[0]], rtol=1e-5,
                               atol=1e-6)
    with open(truth_path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == DEFECT_FIELDS and len(rows) == len(run.defects) > 0


@pytest.mark.parametrize(("name", "minutes", "every", "fs", "message"), [
    ("run.xlsx", 1, 10, 2000, "use .csv, .parquet, .h5 or .mat"),
    ("run.csv", 0, 10, 2000, "must be positive"),
    ("run.csv", 1, -1, 2000, "must be positive"),
    ("run.csv", 1, 10, 50, "at least 100 Hz"),
])
def test_impossible_settings_are_one_line(name: str, minutes: float, every: float, fs: float,
                                          message: str, tmp_path: Path) -> None:
    with pytest.raises(RailwatchError, match=message):
        check_run_settings(tmp_path / name, minutes, every, fs)
    with pytest.raises(RailwatchError, match=message):
        write_run(tmp_path / name, minutes, every_s=every, fs=fs)
    assert list(tmp_path.iterdir()) == []
