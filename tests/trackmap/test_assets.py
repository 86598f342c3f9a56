"""The asset register (``track-map --assets``): reading it, labelling places, and each asset's
response against its kind."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from railwatch import trackmap as tm
from railwatch.errors import RailwatchError
from railwatch.trackmap.assets import Asset, apply, label, read_assets, responses
from support import profiles, scan_folder


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_a_register_by_position_or_by_stretch(tmp_path: Path) -> None:
    reg = read_assets(write(tmp_path / "a.csv", "id,kind,position_m,length_m,owner\n"
                            "S1,Switch,100,30,east\nJ1,insulated_joint,400,,east\n"
                            ",Level-Crossing,200,5,x\n"))
    assert [(a.id, a.kind, a.start_m, a.end_m) for a in reg.assets] == [
        ("S1", "switch", 100.0, 130.0), ("row4", "level crossing", 200.0, 205.0),
        ("J1", "insulated joint", 400.0, 400.0)]
    assert reg.ignored == ("owner",)
    reg = read_assets(write(tmp_path / "b.csv", "kind,start_m,end_m\nbridge transition,10,20\n"))
    assert reg.assets == (Asset("row2", "bridge transition", 10.0, 20.0),)


@pytest.mark.parametrize(("text", "said"), [
    ("id,position_m\nA,1\n", "needs a kind column"),
    ("kind,km\nswitch,1\n", "either position_m"),
    ("kind,position_m\nswitch,one\n", "line 2: positions must be numbers"),
    ("kind,start_m,end_m\nswitch,20,10\n", "line 2: the stretch 20-10 m"),
    ("kind,position_m\n,5\n", "line 2: the kind is empty"),
    ("kind,position_m\n", "holds no assets"),
    ("id,kind,position_m\nA,switch,1\nA,weld,9\n", "ids must be unique (A"),
    ("id,kind,position_m,length_m\nA,switch,100,30\nB,weld,120,1\n",
     "assets A (100-130 m) and B (120-121 m) overlap"),
])
def test_a_bad_register_is_one_line(tmp_path: Path, text: str, said: str) -> None:
    with pytest.raises(RailwatchError) as e:
        read_assets(write(tmp_path / "r.csv", text))
    assert said in str(e.value) and "\n" not in str(e.value), str(e.value)


def test_touching_assets_do_not_overlap(tmp_path: Path) -> None:
    reg = read_assets(write(tmp_path / "r.csv", "kind,position_m,length_m\n"
                            "crossing,535.6855,0.405\nswitch,536.0904,0.4446\n"))
    assert [a.kind for a in reg.assets] == ["crossing", "switch"]


def test_an_asset_at_a_place_labels_it_and_the_nearest_other_does_not() -> None:
    assets = [Asset("S", "switch", 100.0, 130.0), Asset("J", "insulated joint", 140.0, 140.0),
              Asset("W", "weld", 300.0, 300.5)]
    tags = label([125.0, 137.0, 143.5, 200.0, 306.0], assets, tolerance_m=5.0)
    # Inside the switch (the joint, 15 m on, is not); between the switch's end (7 m) and the
    # joint (3 m): the joint; beside the joint; on nothing; 5.5 m past the weld: nothing.
    assert [t.id if t else None for t in tags] == ["S", "J", "J", None, None]


def test_an_asset_louder_than_its_kind_is_abnormal_and_the_others_are_not() -> None:
    """Eight switches answer alike on every pass, one twice as strongly; the passes differ in
    speed (their scores scale), so only a comparison within each pass sees it."""
    rng = np.random.default_rng(0)
    switches = [Asset(f"S{i}", "switch", 250.0 + 500 * i, 260.0 + 500 * i) for i in range(8)]
    welds = [Asset(f"W{i}", "weld", 500.0 + 1000 * i, 500.5 + 1000 * i) for i in range(3)]
    xs, scores = [], []
    for j in range(10):
        x = np.arange(0.0, 4500.0, 0.25)
        s = rng.exponential(size=len(x))
        for a in switches:
            on = (x >= a.start_m) & (x <= a.end_m)
            s[on] += rng.normal(20.0, 2.0) * (2.0 if a.id == "S5" else 1.0)
        xs.append(x)
        scores.append(s * (1.0 + 3.0 * (j % 3)))
    out = responses(switches + welds, xs, scores, tolerance_m=5.0)
    assert out[0].asset.id == "S5" and out[0].abnormal and out[0].kind_z > 5
    assert not any(r.abnormal for r in out[1:])
    assert all(np.isnan(r.kind_z) for r in out if r.asset.kind == "weld")  # 3: too few
    assert all(r.passes_covered == 10 for r in out)


def test_stable_assets_are_rarely_abnormal() -> None:
    """The flag's false rate on assets that answer alike: 40 switches, 10 passes, 50 lines."""
    rng = np.random.default_rng(1)
    flagged = total = 0
    for _ in range(50):
        switches = [Asset(f"S{i}", "switch", 100.0 + 100 * i, 110.0 + 100 * i)
                    for i in range(40)]
        strength = rng.lognormal(np.log(20.0), 0.3, size=40)  # each its own, every pass
        xs, scores = [], []
        for _ in range(10):
            x = np.arange(0.0, 4100.0, 0.5)
            s = rng.exponential(size=len(x))
            for a, k in zip(switches, strength, strict=True):
                on = (x >= a.start_m) & (x <= a.end_m)
                s[on] += k * rng.lognormal(0.0, 0.3)
            xs.append(x)
            scores.append(s)
        out = responses(switches, xs, scores, tolerance_m=5.0)
        flagged += sum(r.abnormal for r in out)
        total += len(out)
    assert flagged / total <= 0.01, flagged / total


def test_track_map_with_a_register(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    from railwatch.cli import main

    defects = np.array([500.0, 1800.0, 3300.0, 4400.0])
    xs, scores = profiles(6, defects, bump=4.0, seed=3)
    scan_folder(tmp_path, xs, scores, defects)
    register = write(tmp_path / "register.csv", "id,kind,position_m,length_m\n"
                     "X1,crossing,1798,3\nX2,crossing,2500,3\nX9,switch,9000,30\n")
    out = tmp_path / "m.csv"
    assert main(["track-map", "--events", str(tmp_path), "--out", str(out),
                 "--assets", str(register), "--plot", str(tmp_path / "m.png")]) == 0
    assert (tmp_path / "m.png").stat().st_size > 10_000
    err = capsys.readouterr().err
    assert "3 reported unexplained, 1 on assets (2 assets on the line, 1 off the stretch " \
           "the passes covered: left out)" in err, err
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    on = {r["asset"] for r in rows if abs(float(r["position_m"]) - 1800) <= 2}
    assert on == {"X1"}
    assert all(r["asset"] == "unexplained" for r in rows
               if abs(float(r["position_m"]) - 1800) > 10)
    with open(tmp_path / "m.assets.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert [r["id"] for r in table] == ["X1", "X2"]
    assert table[0]["place_rank"] and not table[1]["place_rank"]
    assert float(table[0]["response"]) > float(table[1]["response"])
    with open(tmp_path / "m.worklist.csv", newline="") as fh:
        work = list(csv.DictReader(fh))
    assert len(work) == 3 and {r["what"] for r in work} == {"unexplained"}  # X1 is normal
    # No register: the columns stay, empty.
    assert main(["track-map", "--events", str(tmp_path), "--out", str(out)]) == 0
    with open(out, newline="") as fh:
        assert {r["asset"] for r in csv.DictReader(fh)} == {""}
    capsys.readouterr()
    # A bad register fails before any work, in one line.
    bad = write(tmp_path / "bad.csv", "kind\nswitch\n")
    assert main(["track-map", "--events", str(tmp_path), "--out", str(out),
                 "--assets", str(bad)]) != 0
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "needs a kind column and either position_m" in err, err


def test_apply_without_scores_labels_only() -> None:
    loc = tm.Location(rank=1, position_m=10.0, start_m=9.0, end_m=11.0, evidence=float("nan"),
                      false_per_km=float("nan"), passes_seen=2, passes_covered=2, share=1.0,
                      confidence=0.5, median_score=3.0, channel="a", group="g", kind_guess="",
                      first_seen="p1", last_seen="p2")
    reg = tm.assets.Register((Asset("A", "weld", 12.0, 12.5), Asset("B", "weld", 900.0, 901.0)))
    done = apply([loc], reg, (0.0, 100.0), 5.0)
    assert done.places[0].asset == "A" and done.places[0].asset_kind == "weld"
    assert done.responses == [] and [a.id for a in done.off_line] == ["B"]
