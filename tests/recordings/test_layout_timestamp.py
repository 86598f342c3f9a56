"""The layout's timestamp column: when a recording began, in every format."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from railwatch.errors import RailwatchError
from railwatch.recordings.layout import layout_toml, load_layout, parse_layout
from railwatch.recordings.readers import recording_start, write_recording

T0 = 1772352900.0  # 2026-03-01T08:15:00Z


def test_the_key_round_trips_and_stays_out_of_old_model_files(tmp_path: Path) -> None:
    layout = parse_layout({"fs": 100.0, "channels": ["a"], "timestamp": "utc"})
    assert layout.timestamp == "utc" and "utc" not in layout.columns
    (tmp_path / "l.toml").write_text(layout_toml(layout))
    assert load_layout(tmp_path / "l.toml") == layout
    assert "timestamp" not in parse_layout({"fs": 1.0, "channels": ["a"]}).to_dict()
    with pytest.raises(RailwatchError, match="'a' is both a channel and one of time/speed"):
        parse_layout({"fs": 100.0, "channels": ["a"], "timestamp": "a"})


@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".h5", ".mat"])
def test_seconds_since_1970_in_every_format(tmp_path: Path, suffix: str) -> None:
    layout = parse_layout({"fs": 100.0, "channels": ["a"], "timestamp": "utc"})
    path = write_recording(tmp_path / f"x{suffix}",
                           {"a": np.zeros(10), "utc": T0 + np.arange(10) / 100})
    assert recording_start(path, layout) == "2026-03-01T08:15:00Z"
    assert recording_start(path, parse_layout({"fs": 100.0, "channels": ["a"]})) is None


def test_date_times_with_and_without_a_zone(tmp_path: Path) -> None:
    layout = parse_layout({"fs": 100.0, "channels": ["a"], "timestamp": "utc"})
    pd.DataFrame({"a": np.zeros(3), "utc": ["2026-03-01T09:15:00+01:00"] * 3}).to_csv(
        tmp_path / "z.csv", index=False)
    assert recording_start(tmp_path / "z.csv", layout) == "2026-03-01T08:15:00Z"
    pd.DataFrame({"a": np.zeros(3), "utc": pd.to_datetime(["2026-03-01 08:15:07"] * 3)}) \
        .to_parquet(tmp_path / "n.parquet")
    assert recording_start(tmp_path / "n.parquet", layout) == "2026-03-01T08:15:07"
    pd.DataFrame({"a": np.zeros(3), "utc": ["soon"] * 3}).to_csv(tmp_path / "b.csv",
                                                                  index=False)
    with pytest.raises(RailwatchError, match="b.csv: timestamp column 'utc': 'soon' is not a"):
        recording_start(tmp_path / "b.csv", layout)
    pd.DataFrame({"a": np.zeros(3)}).to_csv(tmp_path / "m.csv", index=False)
    with pytest.raises(RailwatchError, match="m.csv: cannot read its timestamp column 'utc'"):
        recording_start(tmp_path / "m.csv", layout)
