"""Assets learned from the passes (``track-map --learn-assets``): a place on both rails alike,
on nearly every pass, is proposed; a one-rail place or one that answers on few passes is not,
unless it is a turnout's crossing nose beside its switch; the proposal is a register that
``--assets`` reads back; one-line errors."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from railwatch.cli import main
from railwatch.trackmap.assets import read_assets
from railwatch.trackmap.learned import LEAD_M
from support import write_pass

#: Both rails alike on every pass (a switch, a level crossing); one rail (a squat); both rails
#: alike on every other pass only.
ASSET, DEFECT, NOW_AND_THEN = 1000.0, 2500.0, 4000.0


def line(folder: Path, passes: int = 8) -> Path:
    rng = np.random.default_rng(3)
    folder.mkdir()
    for j in range(passes):
        x = np.arange(0, 5_000.0, 0.25) + rng.uniform(0, 0.25)
        s = rng.exponential(size=(len(x), 2))
        for at, other, every in ((ASSET, 1.0, 1), (DEFECT, 0.25, 1), (NOW_AND_THEN, 1.0, 2)):
            if j % every == 0:
                near = np.abs(x - at) <= 0.4
                s[near, 0] += 14.0 * (2.0 if every > 1 else 1.0)
                s[near, 1] += 14.0 * other * (2.0 if every > 1 else 1.0)
        write_pass(folder, f"pass{j:02d}", x, x / 20.0, s, ("axle_1", "axle_2"),
                   ("axle", "axle"), np.array([ASSET, DEFECT]))
    return folder


def items_line(folder: Path, items: list[tuple[float, float, float]], passes: int = 8) -> Path:
    """Passes over ``items``: (position m, left rail's and right rail's added score), each on
    every pass."""
    rng = np.random.default_rng(5)
    folder.mkdir()
    for j in range(passes):
        x = np.arange(0, 5_000.0, 0.25) + rng.uniform(0, 0.25)
        s = rng.exponential(size=(len(x), 2))
        for at, left, right in items:
            near = np.abs(x - at) <= 0.4
            s[near, 0] += left
            s[near, 1] += right
        write_pass(folder, f"pass{j:02d}", x, x / 20.0, s, ("axle_1", "axle_2"),
                   ("axle", "axle"), np.array([it[0] for it in items]))
    return folder


def rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_a_place_on_both_rails_on_every_pass_is_learned(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    scans = line(tmp_path / "scan")
    out = tmp_path / "m.csv"
    assert main(["track-map", "--events", str(scans), "--out", str(out), "--learn-assets"]) == 0
    assert "1 assets learned from the passes" in capsys.readouterr().err
    learned = rows(tmp_path / "m.learned-assets.csv")
    assert len(learned) == 1 and learned[0]["id"] == "L1" and learned[0]["kind"] == "learned"
    assert float(learned[0]["start_m"]) <= ASSET + 3 and float(learned[0]["end_m"]) >= ASSET - 3
    assert float(learned[0]["rails_alike"]) > 0.8
    assert learned[0]["passes_answered"] == learned[0]["passes_covered"] == "8"
    mapped = [r for r in rows(out) if float(r["false_per_km"]) <= 0.1]
    label = {round(float(r["position_m"]) / 500) * 500: r["asset"] for r in mapped}
    assert label == {1000: "L1", 2500: "unexplained", 4000: "unexplained"}
    # The proposal is a register: given back, it labels the same place.
    register = read_assets(tmp_path / "m.learned-assets.csv")
    assert [a.id for a in register.assets] == ["L1"] and "rails_alike" in register.ignored
    again = tmp_path / "again.csv"
    assert main(["-q", "track-map", "--events", str(scans), "--out", str(again), "--assets",
                 str(tmp_path / "m.learned-assets.csv")]) == 0
    assert [r["asset"] for r in rows(again) if r["asset"] != "unexplained"] == ["L1"]


def test_a_crossing_nose_is_learned_beside_its_switch(tmp_path: Path) -> None:
    # A switch (both rails); 25 m on, its crossing nose (one rail, stronger); nearer the switch
    # a weaker one-rail place; beyond a turnout's lead a strong one; far off a defect.
    switch, nose, weaker, beyond, far = 1000.0, 1025.0, 990.0, 1000.0 + LEAD_M + 20, 2500.0
    scans = items_line(tmp_path / "scan", [(switch, 20.0, 20.0), (nose, 6.0, 30.0),
                                           (weaker, 10.0, 2.0), (beyond, 30.0, 6.0),
                                           (far, 30.0, 6.0)])
    out = tmp_path / "m.csv"
    assert main(["-q", "track-map", "--events", str(scans), "--out", str(out),
                 "--learn-assets"]) == 0
    learned = {r["id"]: r for r in rows(tmp_path / "m.learned-assets.csv")}
    assert sorted(learned) == ["L1", "L2"], learned
    assert float(learned["L1"]["rails_alike"]) > 0.8 and learned["L1"]["beside"] == ""
    assert float(learned["L2"]["rails_alike"]) < 0.5 and learned["L2"]["beside"] == "L1"
    assert float(learned["L2"]["start_m"]) <= nose <= float(learned["L2"]["end_m"])
    mapped = [r for r in rows(out) if float(r["false_per_km"]) <= 0.1]
    label = {round(float(r["position_m"])): r["asset"] for r in mapped}
    assert {at: label.get(at) for at in (switch, nose, weaker, beyond, far)} == {
        switch: "L1", nose: "L2", weaker: "unexplained", beyond: "unexplained",
        far: "unexplained"}, label
    # Without the switch, the same nose is a one-rail place like any other.
    alone = items_line(tmp_path / "alone", [(nose, 6.0, 30.0), (far, 30.0, 6.0)])
    assert main(["-q", "track-map", "--events", str(alone), "--out", str(tmp_path / "a.csv"),
                 "--learn-assets"]) == 0
    assert rows(tmp_path / "a.learned-assets.csv") == []


def test_learning_needs_the_rails_apart_and_no_register(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    scans = line(tmp_path / "scan", passes=4)
    (tmp_path / "r.csv").write_text("kind,position_m\nswitch,1000\n")
    for extra, said in ((["--sides", "group"], "--sides swap, keep or auto"),
                        (["--assets", str(tmp_path / "r.csv")], "not both"),
                        (["--method", "votes"], "needs the fused map")):
        assert main(["track-map", "--events", str(scans), "--out", str(tmp_path / "m.csv"),
                     "--learn-assets", *extra]) != 0
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and said in err, err
        assert not (tmp_path / "m.learned-assets.csv").exists()
