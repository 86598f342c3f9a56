"""The layout's latitude and longitude columns: a recording's route (its GNSS fixes), in every
format, and one-line errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from railwatch.errors import RailwatchError
from railwatch.recordings.layout import layout_toml, load_layout, parse_layout
from railwatch.recordings.readers import recording_route, write_recording

GNSS = {"fs": 100.0, "channels": ["a"], "latitude": "lat", "longitude": "lon"}


def test_the_keys_round_trip_and_come_in_pairs(tmp_path: Path) -> None:
    layout = parse_layout(GNSS)
    assert (layout.latitude, layout.longitude) == ("lat", "lon")
    assert "lat" not in layout.columns  # not streamed with the channels
    (tmp_path / "l.toml").write_text(layout_toml(layout))
    assert load_layout(tmp_path / "l.toml") == layout
    assert "latitude" not in parse_layout({"fs": 1.0, "channels": ["a"]}).to_dict()
    with pytest.raises(RailwatchError, match="name both latitude and longitude"):
        parse_layout({"fs": 100.0, "channels": ["a"], "latitude": "lat"})


@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".h5", ".mat"])
def test_the_route_every_tenth_of_a_second_in_every_format(tmp_path: Path, suffix: str) -> None:
    n = 1234
    lat = 51.0 + np.arange(n) * 1e-7  # 1 cm a sample: float64 kept
    lon = np.full(n, 10.0)
    lon[500:520] = np.nan  # no fix there
    path = write_recording(tmp_path / f"r{suffix}", {"a": np.zeros(n), "lat": lat, "lon": lon})
    route = recording_route(path, parse_layout(GNSS))
    assert route is not None
    assert route[0].tolist() == [0.0, 51.0, 10.0]
    assert np.allclose(np.diff(route[:3, 0]), 0.1)
    assert route[-1, 0] == pytest.approx((n - 1) / 100) and route[-1, 1] == lat[-1]
    assert len(route) == len(range(0, n, 10)) - 2 + 1  # two fixes missing, the last added
    assert recording_route(path, parse_layout({"fs": 100.0, "channels": ["a"]})) is None


def test_a_time_column_counts_the_route_as_the_scan_does(tmp_path: Path) -> None:
    n = 300
    t = 5.0 + np.arange(n) / 100
    path = write_recording(tmp_path / "r.csv", {"a": np.zeros(n), "t": t,
                                                "lat": np.full(n, 1.0), "lon": np.full(n, 2.0)})
    route = recording_route(path, parse_layout({**GNSS, "time": "t"}))
    assert route is not None and route[0, 0] == 5.0 and route[1, 0] == pytest.approx(5.1)


def test_positions_that_are_not_degrees_are_one_line(tmp_path: Path) -> None:
    n = 50
    path = write_recording(tmp_path / "r.csv", {"a": np.zeros(n), "lat": np.full(n, 5.7e6),
                                                "lon": np.full(n, 1.0)})
    with pytest.raises(RailwatchError, match=r"column 'lat' holds 5.7e\+06 at row 1: GNSS fixes "
                                             r"are degrees \(WGS 84\), within ±90"):
        recording_route(path, parse_layout(GNSS))
    with pytest.raises(RailwatchError, match="has no column 'lon'"):
        recording_route(write_recording(tmp_path / "s.csv", {"a": np.zeros(n),
                                                             "lat": np.zeros(n)}),
                        parse_layout(GNSS))
