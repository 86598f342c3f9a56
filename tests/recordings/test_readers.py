"""Recording readers: every format round-trips, streams in blocks, and fails in one clear line."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from railwatch.errors import RailwatchError
from railwatch.recordings.layout import Layout, layout_toml, load_layout, parse_layout
from railwatch.recordings.readers import Recording, write_recording
from support import write_mat73

FS = 200.0
LAYOUT = Layout(fs=FS, channels=("a", "b"), groups=("axle", "body"), time="t", speed="v")


def columns(n: int = 500, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"t": 10.0 + np.arange(n) / FS, "v": np.full(n, 20.0),
            "a": rng.normal(size=n), "b": rng.normal(size=n), "unused": np.zeros(n)}


@pytest.mark.parametrize("ext", [".csv", ".parquet", ".h5", ".mat", ".mat73"])
def test_every_format_round_trips_and_streams(tmp_path: Path, ext: str) -> None:
    cols = columns()
    if ext == ".mat73":
        path = tmp_path / "rec.mat"
        write_mat73(path, cols)
    else:
        path = write_recording(tmp_path / f"rec{ext}", cols)
    rec = Recording(path, LAYOUT)
    assert rec.n_samples == 500 and rec.duration_s == pytest.approx(2.5)
    whole = rec.read()
    np.testing.assert_allclose(whole.data, np.stack([cols["a"], cols["b"]], 1), rtol=1e-6,
                               atol=1e-6)
    np.testing.assert_allclose(whole.time, cols["t"], rtol=1e-9)
    assert whole.speed is not None and whole.position is None
    blocks = list(rec.chunks(rows=77))
    assert [b.start for b in blocks] == list(range(0, 500, 77))
    np.testing.assert_array_equal(np.concatenate([b.data for b in blocks]), whole.data)


def csv_with(tmp_path: Path, cols: dict[str, object]) -> Path:
    import pandas as pd

    path = tmp_path / "bad.csv"
    pd.DataFrame(cols).to_csv(path, index=False)
    return path


def test_missing_column(tmp_path: Path) -> None:
    cols = columns()
    del cols["b"]
    for ext in (".csv", ".parquet", ".h5", ".mat"):
        path = write_recording(tmp_path / f"r{ext}", cols)
        with pytest.raises(RailwatchError, match=r"no (column|dataset|variable) 'b'"):
            Recording(path, LAYOUT)


def test_non_numeric_value_names_column_and_row(tmp_path: Path) -> None:
    cols: dict[str, object] = {k: list(v) for k, v in columns(20).items()}
    cols["b"][7] = "abc"  # type: ignore[index]
    with pytest.raises(RailwatchError, match=r"column 'b' is not numeric: 'abc' at row 8"):
        Recording(csv_with(tmp_path, cols), LAYOUT).read()
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.table({**columns(20), "b": pa.array(["x"] * 20)})
    pq.write_table(table, tmp_path / "s.parquet")
    with pytest.raises(RailwatchError, match="column 'b' is not numeric"):
        Recording(tmp_path / "s.parquet", LAYOUT)


def test_nan_names_column_and_row(tmp_path: Path) -> None:
    cols = columns(50)
    cols["a"][30] = np.nan
    with pytest.raises(RailwatchError, match=r"column 'a' is NaN or empty at row 31"):
        Recording(write_recording(tmp_path / "n.parquet", cols), LAYOUT).read()


def test_gap_and_rate_and_order_of_time(tmp_path: Path) -> None:
    cols = columns(400)
    cols["t"] = np.r_[cols["t"][:300], cols["t"][300:] + 0.5]  # half a second missing
    rec = Recording(write_recording(tmp_path / "gap.parquet", cols), LAYOUT)
    gap = r"gap in time column 't': 0.5 s missing after t = 11.495 s \(row 300\)"
    with pytest.raises(RailwatchError, match=gap):
        rec.read()
    with pytest.raises(RailwatchError, match="gap"):  # also across block boundaries
        list(rec.chunks(rows=300))
    cols = columns(400)
    with pytest.raises(RailwatchError, match=r"\(100 Hz\) but the layout says fs = 200 Hz"):
        Recording(write_recording(tmp_path / "rate.h5", {**cols, "t": np.arange(400) / 100.0}),
                  LAYOUT).read()
    back = cols["t"].copy()
    back[10] = back[8]
    with pytest.raises(RailwatchError, match="does not increase at row 11"):
        Recording(write_recording(tmp_path / "back.h5", {**cols, "t": back}), LAYOUT).read()


def test_file_errors(tmp_path: Path) -> None:
    with pytest.raises(RailwatchError, match="no such recording"):
        Recording(tmp_path / "none.csv", LAYOUT)
    (tmp_path / "x.xlsx").write_text("x")
    with pytest.raises(RailwatchError, match="unknown format .xlsx"):
        Recording(tmp_path / "x.xlsx", LAYOUT)
    (tmp_path / "junk.parquet").write_text("not parquet")
    with pytest.raises(RailwatchError, match="cannot read .* as Parquet"):
        Recording(tmp_path / "junk.parquet", LAYOUT)
    (tmp_path / "junk.h5").write_text("not hdf5")
    with pytest.raises(RailwatchError, match="cannot read .* as HDF5"):
        Recording(tmp_path / "junk.h5", LAYOUT)
    import h5py

    with h5py.File(tmp_path / "2d.h5", "w") as f:
        f["a"] = np.zeros((10, 3))
        f["b"] = f["t"] = f["v"] = np.zeros(10)
    with pytest.raises(RailwatchError, match="'a' has shape"):
        Recording(tmp_path / "2d.h5", LAYOUT)


def test_layout_files_and_errors(tmp_path: Path) -> None:
    path = tmp_path / "layout.toml"
    path.write_text(layout_toml(LAYOUT))
    assert load_layout(path) == LAYOUT
    (tmp_path / "layout.yaml").write_text("fs: 200\nchannels: [a, b]\ntime: t\nspeed: v\n")
    assert load_layout(tmp_path / "layout.yaml").channels == ("a", "b")
    assert load_layout(tmp_path / "layout.yaml").scale == "field"  # a real rail unless said
    bench = replace(LAYOUT, scale="benchmark")
    path.write_text(layout_toml(bench))
    assert load_layout(path) == bench and "scale" in path.read_text()
    assert LAYOUT.select(("body",)).channels == ("b",)
    with pytest.raises(RailwatchError, match="no channel of group bogie"):
        LAYOUT.select(("bogie",))
    for values, message in [
        ({"channels": ["a"]}, "'fs'"),
        ({"fs": "fast", "channels": ["a"]}, "fs must be a number"),
        ({"fs": 100}, "'channels' must list"),
        ({"fs": 100, "channels": ["a", "a"]}, "named twice"),
        ({"fs": 100, "channels": ["a"], "speeed": "v"}, "unknown key"),
        ({"fs": 100, "channels": ["a"], "time": "a"}, "both a channel"),
        ({"fs": 100, "channels": ["a", "b"], "groups": ["x"]}, "1 groups for 2 channels"),
        ({"fs": 100, "channels": ["a"], "scale": "paper"}, "scale is 'paper'"),
    ]:
        with pytest.raises(RailwatchError, match=message):
            parse_layout(values)
    (tmp_path / "bad.toml").write_text("fs = = 2")
    with pytest.raises(RailwatchError, match="cannot parse layout"):
        load_layout(tmp_path / "bad.toml")
    with pytest.raises(RailwatchError, match="no such layout file"):
        load_layout(tmp_path / "none.toml")


def test_errors_name_the_file_and_short_blocks_do_not_fake_a_rate(tmp_path: Path) -> None:
    cols = columns(250)
    cols["t"][-1] += 0.3 / FS  # a late last sample, alone in its block: jitter, not a rate
    rec = Recording(write_recording(tmp_path / "late.parquet", cols), LAYOUT)
    assert len(rec.read()) == 250
    assert sum(len(b) for b in rec.chunks(rows=249)) == 250
    cols = columns(50)
    cols["a"][3] = np.inf
    with pytest.raises(RailwatchError, match=r"^inf.h5: column 'a' is infinite at row 4"):
        Recording(write_recording(tmp_path / "inf.h5", cols), LAYOUT).read()


def test_odd_hdf5_and_mat_files(tmp_path: Path) -> None:
    import h5py

    with h5py.File(tmp_path / "scalar.h5", "w") as f:
        f["a"] = 1.0
        f["b"] = f["t"] = f["v"] = np.zeros(10)
    with pytest.raises(RailwatchError, match=r"'a' has shape \(\)"):
        Recording(tmp_path / "scalar.h5", LAYOUT)
    with h5py.File(tmp_path / "3d.h5", "w") as f:
        f["a"] = np.zeros((10, 1, 1))
        f["b"] = f["t"] = f["v"] = np.zeros(10)
    with pytest.raises(RailwatchError, match="'a' has shape"):
        Recording(tmp_path / "3d.h5", LAYOUT)
    good = write_recording(tmp_path / "good.mat", columns(20))
    (tmp_path / "cut.mat").write_bytes(good.read_bytes()[:200])
    with pytest.raises(RailwatchError, match="cannot read .* as a MATLAB file"):
        Recording(tmp_path / "cut.mat", LAYOUT)
