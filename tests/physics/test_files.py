"""``railwatch simulate``: the folder it writes, read back as recordings; one-line errors."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from railwatch.cli import main
from railwatch.evaluation.maps import read_truth
from railwatch.recordings.layout import load_layout
from railwatch.recordings.readers import Recording


def test_simulate_writes_passes_twins_and_truth(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "phys"
    assert main(["simulate", "--out", str(out), "--passes", "2", "--track-km", "0.8",
                 "--seed", "3", "--speed", "15-25", "--format", "csv"]) == 0
    assert "wrote 2 passes over 0.8 km" in capsys.readouterr().err
    layout = load_layout(out / "layout.toml")
    assert layout.fs == 2000.0 and layout.groups == ("axle", "axle", "bogie", "bogie", "body",
                                                     "body")
    truth = read_truth(out / "track.defects.csv")
    info = json.loads((out / "physics.json").read_text())
    assert [p["direction"] for p in info["passes"]] == [1, -1]
    assert info["sensor_noise_ms2"]["axle_left"] == pytest.approx(0.1)
    for name in ("pass01", "pass02"):
        rec = Recording(out / f"{name}.csv", layout)
        twin = Recording(out / "twins" / f"{name}.csv", layout)
        assert rec.duration_s == pytest.approx(twin.duration_s)
        with open(out / f"{name}.defects.csv", newline="") as fh:
            rows = list(csv.DictReader(fh))
        assert rows and {r["kind"] for r in rows} <= {"squat", "joint", "weld", "step",
                                                      "corrugation"}
        starts = {round(float(r["position_m"]), 3) for r in rows}
        assert starts <= {round(float(s), 3) for s in truth[:, 0]}
        # The twin's position is the true one; the odometry's is within a few metres of it.
        import pandas as pd

        twin_cols = pd.read_csv(out / "twins" / f"{name}.csv")
        for r in rows:
            centre = float(r["position_m"]) + float(r["length_m"]) / 2
            at = np.interp(float(r["center_s"]), twin_cols["time"], twin_cols["position"])
            assert at == pytest.approx(centre, abs=0.05)
            assert abs(float(r["recorded_m"]) - float(r["position_m"])) < 10
            assert 15 <= float(r["speed_ms"]) <= 25
            assert r["channel"] in ("axle_left", "axle_right")
    assert (out / "track.features.csv").is_file() and (out / "pass01.features.csv").is_file()
    # The features as an asset register that track-map --assets reads.
    from railwatch.trackmap.assets import read_assets

    with open(out / "track.features.csv", newline="") as fh:
        features = list(csv.DictReader(fh))
    register = read_assets(out / "track.assets.csv")
    assert len(register.assets) == len(features) > 0 and not register.ignored
    assert {a.kind for a in register.assets} <= {"switch", "crossing", "bridge transition",
                                                 "level crossing"}
    assert sorted(a.start_m for a in register.assets) == sorted(
        float(r["position_m"]) for r in features)


def test_simulate_is_reproducible(tmp_path: Path) -> None:
    for name in ("a", "b"):
        assert main(["-q", "simulate", "--out", str(tmp_path / name), "--passes", "1",
                     "--track-km", "0.4", "--seed", "5"]) == 0
    import pandas as pd

    a, b = (pd.read_parquet(tmp_path / n / "pass01.parquet") for n in ("a", "b"))
    np.testing.assert_array_equal(a.to_numpy(), b.to_numpy())


@pytest.mark.parametrize("args, message", [
    (["--speed", "50-60"], "speeds 50-60 m/s"),
    (["--speed", "fast"], "--speed 'fast'"),
    (["--fs", "50"], "--fs 50 Hz"),
    (["--irregularity", "bumpy"], "irregularity 'bumpy'"),
    (["--track-km", "0.1"], "--track-km"),
    (["--start", "soon"], "--start soon: give a date-time"),
    (["--every-days", "0"], "--every-days 0: give a positive number"),
    (["--growing", "2"], "--growing"),
])
def test_impossible_settings_are_one_line_errors(tmp_path: Path, capsys, args,  # type: ignore[no-untyped-def]
                                                 message) -> None:
    out = tmp_path / "x"
    assert main(["simulate", "--out", str(out), *args]) != 0
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (out / "track.defects.csv").exists()


def test_train_at_field_scale_sets_the_matched_filter_for_the_rate(tmp_path: Path,
                                                                   capsys) -> None:  # type: ignore[no-untyped-def]
    from railwatch.detectors import load_detector

    out = tmp_path / "phys"
    assert main(["-q", "simulate", "--out", str(out), "--passes", "1", "--track-km", "0.4",
                 "--seed", "2"]) == 0
    common = ["train", "--detector", "matched-filter", "--recordings",
              str(out / "pass01.parquet"), "--layout", str(out / "layout.toml")]
    assert main([*common, "--out", str(tmp_path / "m")]) == 0
    assert ("matched-filter with order=16, energy_boxes=8,16,32,64, change_point=False"
            in capsys.readouterr().err)
    cfg = load_detector(tmp_path / "m").config
    assert cfg.order == 16 and cfg.energy_boxes == (8, 16, 32, 64) and not cfg.change_point
    # --set wins: the benchmark's matched filter on the same recording.
    assert main([*common, "--out", str(tmp_path / "b"), "--set", "order=8",
                 "--set", "energy_boxes=", "--set", "change_point=true"]) == 0
    cfg = load_detector(tmp_path / "b").config
    assert cfg.order == 8 and cfg.energy_boxes == () and cfg.change_point
    # The event threshold: 0.1 windows per minute of the training null at field scale.
    window_s = json.loads((tmp_path / "m" / "recording.json").read_text())["preparation"][
        "window_s"]
    rules = {n: json.loads((tmp_path / n / "recording.json").read_text())["threshold_rule"]
             for n in ("m", "b")}
    assert rules["m"] == rules["b"] == f"gumbel_null(tail={round(0.1 * window_s / 60, 12):g})"
    assert main([*common, "--out", str(tmp_path / "r"), "--events-per-minute", "2"]) == 0
    rule = json.loads((tmp_path / "r" / "recording.json").read_text())["threshold_rule"]
    assert rule == f"gumbel_null(tail={round(2 * window_s / 60, 12):g})"
    assert load_detector(tmp_path / "r").threshold_ < load_detector(tmp_path / "m").threshold_


@pytest.mark.parametrize("rate, message", [
    ("0", "--events-per-minute must be positive"),
    ("-1", "--events-per-minute must be positive"),
    ("1000", "puts half of the"),
])
def test_an_impossible_event_rate_is_a_one_line_error(tmp_path: Path, capsys, rate,  # type: ignore[no-untyped-def]
                                                      message) -> None:
    out = tmp_path / "phys"
    assert main(["-q", "simulate", "--out", str(out), "--passes", "1", "--track-km", "0.4",
                 "--seed", "2"]) == 0
    capsys.readouterr()
    assert main(["train", "--detector", "matched-filter", "--recordings",
                 str(out / "pass01.parquet"), "--layout", str(out / "layout.toml"),
                 "--events-per-minute", rate, "--out", str(tmp_path / "m")]) != 0
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "m").exists()


def test_dated_passes_over_growing_squats(tmp_path: Path) -> None:
    """--start dates every pass (a utc column the layout names); --growing deepens the chosen
    squats linearly in time and lengthens them with it, the others and the clean twins
    unchanged."""
    from railwatch.recordings.readers import recording_start

    out = tmp_path / "w"
    assert main(["-q", "simulate", "--out", str(out), "--passes", "3", "--track-km", "1.2",
                 "--seed", "8", "--start", "2026-01-05T06:00Z", "--every-days", "14",
                 "--growing", "0.5"]) == 0
    layout = load_layout(out / "layout.toml")
    assert layout.timestamp == "utc"
    assert [recording_start(out / f"pass0{i}.parquet", layout) for i in (1, 2, 3)] == [
        "2026-01-05T06:00:00Z", "2026-01-19T06:00:00Z", "2026-02-02T06:00:00Z"]
    with open(out / "track.defects.csv", newline="") as fh:
        squats = {r["defect"]: r for r in csv.DictReader(fh) if r["kind"] == "squat"}
    growth = {d: float(r["detail"].split("growth=")[1]) for d, r in squats.items()
              if "growth=" in r["detail"]}
    assert len(growth) == round(0.5 * len(squats)) > 0
    assert all(1.2 <= g <= 3.0 for g in growth.values())
    seen = 0
    for i in (1, 2, 3):
        with open(out / f"pass0{i}.defects.csv", newline="") as fh:
            for r in csv.DictReader(fh):
                if r["kind"] != "squat":
                    continue
                was = squats[r["defect"]]
                first = float(was["depth_mm"])
                g = growth.get(r["defect"], 1.0)
                f = 1 + (g - 1) * (i - 1) / 2
                assert float(r["depth_mm"]) == pytest.approx(first * f, rel=1e-3)
                # ... and longer about its centre, as the track's squats are at that depth:
                # 2-10 cm from 0.1 to 1.5 mm, linear in the log of the depth.
                grew = 0.08 * np.log(f) / np.log(15.0)
                assert float(r["length_m"]) == pytest.approx(float(was["length_m"]) + grew,
                                                             abs=2e-4)
                centre = float(r["position_m"]) + float(r["length_m"]) / 2
                assert centre == pytest.approx(float(was["position_m"])
                                               + float(was["length_m"]) / 2, abs=2e-4)
                seen += r["defect"] in growth and i > 1
    assert seen > 0


def test_simulated_passes_carry_gnss_fixes_along_the_line(tmp_path: Path) -> None:
    """lat/lon columns: each fix within a few σ of where the pass truly was, both directions
    on one line; the route a scan keeps reads them at 10 Hz."""
    import pandas as pd

    from railwatch.physics import gnss
    from railwatch.recordings.readers import recording_route

    out = tmp_path / "phys"
    assert main(["simulate", "--out", str(out), "--passes", "2", "--track-km", "0.6",
                 "--seed", "4", "--speed", "20-25", "--format", "parquet"]) == 0
    layout = load_layout(out / "layout.toml")
    assert (layout.latitude, layout.longitude) == ("lat", "lon")
    s, east, north = gnss.line(-300, 1000, 4)
    for name in ("pass01", "pass02"):
        twin = pd.read_parquet(out / "twins" / f"{name}.parquet")
        rec = pd.read_parquet(out / f"{name}.parquet")
        assert np.array_equal(rec["lat"], twin["lat"])  # odometry errors leave GNSS alone
        lat, lon = gnss.to_degrees(np.interp(twin["position"], s, east),
                                   np.interp(twin["position"], s, north))
        north_err = np.radians(rec["lat"] - lat) * gnss.EARTH_RADIUS_M
        assert np.abs(north_err).max() < 5 * gnss.FIX_SIGMA_M
        assert np.abs(north_err).max() > 0.01  # there is an error
        route = recording_route(out / f"{name}.parquet", layout)
        assert route is not None and route.shape[1] == 3
        assert np.median(np.diff(route[:, 0])) == pytest.approx(0.1)
        assert route[-1, 0] == pytest.approx(float(rec["time"].iloc[-1]))
    # As far apart on the earth as along the track, give or take the fixes' error (the line's
    # curves are gentle).
    run = pd.read_parquet(out / "twins" / "pass01.parquet")
    ends = run.iloc[[0, -1]]
    apart = np.hypot(np.radians(np.diff(ends["lat"])) * gnss.EARTH_RADIUS_M,
                     np.radians(np.diff(ends["lon"])) * gnss.EARTH_RADIUS_M
                     * np.cos(np.radians(gnss.ORIGIN[0])))[0]
    along = float(np.ptp(run["position"]))
    assert along > 300 and abs(apart - along) < 0.02 * along + 6 * gnss.FIX_SIGMA_M
