"""Scanning many recordings: the same events locally and on Ray, resumable, one-line errors."""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from railwatch.cli import main
from railwatch.detection import pipeline
from railwatch.detectors import create
from railwatch.errors import RailwatchError
from railwatch.recordings.layout import load_layout
from railwatch.recordings.prepare import Preparation
from railwatch.recordings.readers import Recording
from railwatch.synthetic.track import write_track
from railwatch.trackmap import folder as tf
from railwatch.trackmap.scan import scan
from support import tiny_config


@pytest.fixture(scope="module")
def track(tmp_path_factory):  # type: ignore[no-untyped-def]
    folder = tmp_path_factory.mktemp("track")
    _, paths = write_track(folder, 4, length_m=1500, n_defects=8, seed=2, fs=200.0)
    layout = load_layout(folder / "layout.toml")
    prep = Preparation()
    X = pipeline.training_windows([Recording(paths[0], layout)], prep)
    det = create("matched-filter", tiny_config("matched-filter"))
    pipeline.fit_recording_model(det, X, layout, prep, folder / "model")
    return folder, paths


def events(out: Path) -> list[dict[str, str]]:
    with open(out / "events.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def test_scan_writes_every_recording_and_a_combined_table(track) -> None:  # type: ignore[no-untyped-def]
    folder, paths = track
    out = folder / "scan-local"
    summary = scan(folder / "model", paths, out)
    assert (summary.scanned, summary.reused) == (4, 0)
    rows = events(out)
    assert len(rows) == summary.events > 0
    assert {r["recording"] for r in rows} <= {p.stem for p in paths}
    for p in paths:
        info = json.loads((out / f"{p.stem}.scan.json").read_text())
        assert info["events"] == sum(r["recording"] == p.stem for r in rows)
        assert info["position_first_m"] is not None
        assert info["scale"] == "benchmark"  # generate-run's runs: track-map's --min-events 0
        with np.load(out / f"{p.stem}.profile.npz", allow_pickle=False) as f:
            assert f["channel_score"].shape == (len(f["position_m"]), 6)
            assert list(f["groups"]) == ["axle", "axle", "bogie", "bogie", "body", "body"]
            assert np.isfinite(f["position_m"]).all()
            # An event's peak score is the highest over the windows that cover its peak; the
            # profile keeps the score of the one window the sample is most central in.
            point, t = f["channel_score"].max(axis=1), f["time_s"]
            for r in rows:
                if r["recording"] == p.stem:
                    j = int(np.argmin(np.abs(t - float(r["peak_s"]))))
                    assert point[j] <= float(r["score"]) + 1e-3
    again = scan(folder / "model", paths, out)
    assert (again.scanned, again.reused, again.events) == (0, 4, summary.events)
    # A scan whose profile holds the maximum over windows (before central profiles) is redone.
    info_path = out / f"{paths[0].stem}.scan.json"
    info = json.loads(info_path.read_text())
    del info["profile"]
    info_path.write_text(json.dumps(info))
    redo = scan(folder / "model", paths, out)
    assert (redo.scanned, redo.reused) == (1, 3)


def test_the_folder_module_names_every_file_and_key(track) -> None:  # type: ignore[no-untyped-def]
    """What a scan writes is what ``trackmap.folder`` names, and nothing else."""
    folder, paths = track
    out = folder / "scan-names"
    scan(folder / "model", paths[:1], out)
    stem = paths[0].stem
    suffixes = (tf.SCAN_SUFFIX, tf.EVENTS_SUFFIX, tf.PROFILE_SUFFIX)
    assert sorted(q.name for q in out.iterdir()) == sorted(
        [tf.COMBINED, *(stem + s for s in suffixes)])
    assert tuple(json.loads((out / f"{stem}{tf.SCAN_SUFFIX}").read_text())) == tf.SCAN_KEYS
    with np.load(out / f"{stem}{tf.PROFILE_SUFFIX}", allow_pickle=False) as f:
        assert sorted(f.files) == sorted(tf.PROFILE_ARRAYS)
    with pytest.raises(ValueError, match="not keys of a scan record: speed"):
        tf.scan_record(speed=1.0)


@pytest.mark.slow
def test_ray_gives_the_same_events_as_local(track) -> None:  # type: ignore[no-untyped-def]
    folder, paths = track
    local = folder / "scan-local-ray-ref"
    scan(folder / "model", paths, local)
    on_ray = folder / "scan-ray"
    summary = scan(folder / "model", paths, on_ray, executor="ray")
    assert summary.scanned == 4
    # Same events, same order; scores equal to float32 print precision (one thread each).
    assert events(on_ray) == events(local)


@pytest.mark.slow
def test_a_killed_scan_skips_finished_recordings(track) -> None:  # type: ignore[no-untyped-def]
    folder, paths = track
    out = folder / "scan-killed"
    proc = subprocess.Popen([sys.executable, "-m", "railwatch.cli", "-q", "scan", "--model",
                             str(folder / "model"), "--recordings", *map(str, paths), "--out",
                             str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while not list(out.glob("*.scan.json")) and proc.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    finished = {p: p.stat().st_mtime_ns for p in out.glob("*.scan.json")}
    assert 1 <= len(finished) < 4, "killed too late to test anything"
    summary = scan(folder / "model", paths, out)
    assert summary.reused == len(finished) and summary.scanned == 4 - len(finished)
    assert {p: p.stat().st_mtime_ns for p in finished} == finished
    reference = folder / "scan-whole"
    scan(folder / "model", paths, reference)
    assert events(out) == events(reference)


def test_bad_input_is_one_line(track, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    folder, paths = track
    other = tmp_path / "other.layout.toml"
    text = (folder / "layout.toml").read_text().replace('"axle_1" = "axle"', '"wheel" = "axle"')
    other.write_text(text)
    code = main(["-q", "scan", "--model", str(folder / "model"), "--recordings", str(paths[0]),
                 "--layout", str(other), "--out", str(tmp_path / "s")])
    err = capsys.readouterr().err
    assert code == 1 and err.startswith("railwatch: error: ") and err.count("\n") == 1, err
    assert not (tmp_path / "s").exists()  # checked before any work
    with pytest.raises(RailwatchError, match="no recording matches"):
        from railwatch.cli.tracks import expand_recordings

        expand_recordings((str(tmp_path / "nothing*.parquet"),))
    code = main(["-q", "track-map", "--events", str(tmp_path), "--out", str(tmp_path / "m.csv")])
    err = capsys.readouterr().err
    assert code == 1 and "holds no scanned recordings" in err and err.count("\n") == 1


def test_dated_passes_from_a_table_are_kept_and_ordered(track, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """scan --dates dates the recordings (a finished one without a new scan); track-map orders
    the passes by date and maps only those between --since and --until."""
    folder, paths = track
    out = tmp_path / "scan"
    assert main(["-q", "scan", "--model", str(folder / "model"), "--recordings",
                 *map(str, paths), "--out", str(out)]) == 0
    undated = [json.loads((out / f"{p.stem}.scan.json").read_text())["started"] for p in paths]
    assert undated == [None] * 4
    dates = tmp_path / "dates.csv"  # pass 1 recorded last; pass 4 undated
    dates.write_text("recording,started\n"
                     f"{paths[0].name},2026-03-01T09:00:00+01:00\n"
                     f"{paths[1]},2026-01-10T08:00:00Z\n"
                     f"{paths[2].stem},1770000000\n")
    assert main(["scan", "--model", str(folder / "model"), "--recordings",
                 *map(str, paths), "--out", str(out), "--dates", str(dates)]) == 0
    assert "(4 scanned before)" in capsys.readouterr().err
    started = [json.loads((out / f"{p.stem}.scan.json").read_text())["started"] for p in paths]
    assert started == ["2026-03-01T08:00:00Z", "2026-01-10T08:00:00Z", "2026-02-02T02:40:00Z",
                       None]
    passes = tf.read_scan(out)
    from railwatch.trackmap.maps import by_date

    ordered, left = by_date(passes)
    assert [p.name for p in ordered] == [paths[i].stem for i in (1, 2, 0, 3)] and not left
    kept, left = by_date(passes, since="2026-02-01", until="2026-03-01")
    assert [p.name for p in kept] == [paths[i].stem for i in (2, 0)]
    assert sorted(p.name for p in left) == sorted(paths[i].stem for i in (1, 3))
    assert main(["track-map", "--events", str(out), "--out", str(tmp_path / "m.csv"),
                 "--until", "2026-02-28"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("2 passes (recorded 2026-01-10 to 2026-02-02; 2 left out by "
                          "--since/--until (undated or outside))"), err
    assert main(["track-map", "--events", str(out), "--out", str(tmp_path / "m.csv")]) == 0
    assert "4 passes (recorded 2026-01-10 to 2026-03-01; 1 undated" in capsys.readouterr().err
    for bad, said in ((["--since", "2026-02-30"], "--since 2026-02-30: give a date"),
                      (["--since", "2026-03-01", "--until", "2026-01-01"], "is before --since"),
                      (["--since", "2027-01-01"], "no pass of")):
        assert main(["track-map", "--events", str(out), "--out", str(tmp_path / "m.csv"),
                     *bad]) != 0
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and said in err, err
    dates.write_text("recording,started\npass01,yesterday\n")
    assert main(["-q", "scan", "--model", str(folder / "model"), "--recordings", str(paths[0]),
                 "--out", str(out), "--dates", str(dates)]) != 0
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "line 2: 'yesterday' is not a date-time" in err, err


def test_a_gnss_layout_keeps_each_recording_route(track, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """With latitude and longitude in the layout, a scan keeps each recording's route (its
    fixes at 10 Hz, timed as its score profile), a recording scanned before without them is
    scanned again, and track-map --geojson puts the places on the earth."""
    from dataclasses import replace

    import pandas as pd

    from railwatch.physics import gnss
    from railwatch.recordings.layout import layout_toml
    from railwatch.recordings.readers import write_recording

    folder, paths = track
    layout = load_layout(folder / "layout.toml")
    s, east, north = gnss.line(-500.0, 5000.0, 0)
    located = []
    for p in paths:
        cols = pd.read_parquet(p)
        x = cols[layout.position].to_numpy()
        cols["lat"], cols["lon"] = gnss.to_degrees(np.interp(x, s, east), np.interp(x, s, north))
        located.append(write_recording(tmp_path / p.name, {c: cols[c].to_numpy() for c in cols}))
    with_gnss = replace(layout, latitude="lat", longitude="lon")
    (tmp_path / "gnss.toml").write_text(layout_toml(with_gnss))
    out = tmp_path / "scan"
    scan(folder / "model", located, out)  # the model's layout: no GNSS
    assert not json.loads((out / f"{paths[0].stem}.scan.json").read_text())["gnss"]
    again = scan(folder / "model", located, out, layout=with_gnss)
    assert (again.scanned, again.reused) == (4, 0)
    for p in located:
        assert json.loads((out / f"{p.stem}.scan.json").read_text())["gnss"]
        with np.load(out / f"{p.stem}{tf.PROFILE_SUFFIX}", allow_pickle=False) as f:
            route, t = f[tf.ROUTE_ARRAY], f["time_s"]
        assert route.shape[1] == 3 and np.median(np.diff(route[:, 0])) == pytest.approx(0.1)
        assert abs(route[0, 0] - t[0]) < 0.2 and abs(route[-1, 0] - t[-1]) < 0.2
    assert scan(folder / "model", located, out, layout=with_gnss).reused == 4
    collection = tmp_path / "m.geojson"
    assert main(["-q", "track-map", "--events", str(out), "--out", str(tmp_path / "m.csv"),
                 "--geojson", str(collection)]) == 0
    placed = [f for f in json.loads(collection.read_text())["features"]
              if f["properties"]["kind"] == "place"]
    assert placed and all(f["geometry"] is not None for f in placed)


def test_a_field_rate_recording_keeps_its_low_band_at_the_profiles_samples(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The axle boxes' highest |acceleration| below 200 Hz: a 600-Hz ring is dropped, a body
    channel's sway left out."""
    import pandas as pd

    from railwatch.recordings.layout import Layout
    from railwatch.recordings.readers import Recording
    from railwatch.trackmap.scan import band_at

    fs = 2_000.0
    t = np.arange(0, 2.0, 1 / fs)
    path = tmp_path / "r.parquet"
    pd.DataFrame({"left": np.sin(2 * np.pi * 600 * t), "right": 0.3 * np.sin(2 * np.pi * 50 * t),
                  "body": 5.0 * np.sin(2 * np.pi * 2 * t)}).to_parquet(path)
    channels, groups = ("left", "right", "body"), ("axle", "axle", "body")
    rec = Recording(path, Layout(fs=fs, channels=channels, groups=groups))
    band = band_at(rec, t)
    assert band is not None and band.shape == (len(t),) and band.dtype == np.float32
    assert 0.28 < band[200:-200].max() < 0.32
    half = band_at(rec, t[::2])  # a profile at another rate: the band at its times
    assert half is not None and np.allclose(half, band[::2], atol=1e-6)
    slow = Recording(path, Layout(fs=100.0, channels=channels, groups=groups))
    assert band_at(slow, t[::20]) is None
