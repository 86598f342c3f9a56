"""Evidence fused across passes: the local calibration, Stouffer's combination, the shifted null,
and maps of synthetic score profiles (weak repeating defects, a loud stretch, pure noise)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from railwatch import trackmap as tm
from railwatch.errors import RailwatchError
from railwatch.evaluation import maps as em
from railwatch.trackmap import fusion
from support import profiles, scan_folder, write_pass

LENGTH = 5_000.0


@pytest.mark.parametrize("stride", [1, 4])
def test_local_scale_equals_brute_force(stride: int) -> None:
    rng = np.random.default_rng(0)
    x = rng.exponential(size=400)
    level, top = fusion.local_scale(x, half=40, stride=stride)
    coarse = x[::stride]
    reach = 40 // stride
    for k in range(reach, len(coarse) - reach):  # windows within the profile
        around = coarse[k - reach:k + reach + 1]
        assert level[k * stride] == pytest.approx(np.median(around))
        # scipy's percentile_filter takes the order statistic at or below the percentile
        rank = int(fusion.SPREAD_PERCENTILE / 100 * (len(around) - 1))
        assert top[k * stride] == pytest.approx(np.sort(around)[rank])


def test_calibrate_ranks_the_local_z_against_the_whole_pass() -> None:
    rng = np.random.default_rng(1)
    x = rng.exponential(size=600)
    x[100:130] = np.nan
    p = fusion.calibrate(x, half=50)
    assert np.isnan(p[100:130]).all() and np.isfinite(np.delete(p, range(100, 130))).all()
    v = x[np.isfinite(x)]
    level, top = fusion.local_scale(v, 50)
    z = (v - level) / (top - level)
    expected = np.array([(z >= zi).sum() / (len(z) + 1) for zi in z])
    assert np.delete(p, range(100, 130)) == pytest.approx(expected)
    # Any score a + b·s (b > 0) is calibrated alike.
    assert fusion.calibrate(3.0 + 7.0 * x, half=50) == pytest.approx(p, nan_ok=True)


def test_calibration_keeps_the_top_for_what_stands_out_of_the_whole_pass() -> None:
    """Ranked within its neighbourhood, every stretch's own highest value took the top p, about
    five places per km of pure noise; ranked against the pass after the local scaling, only
    what is rare in the whole pass does."""
    rng = np.random.default_rng(2)
    x = np.arange(0, LENGTH, 0.25) + rng.uniform(0, 0.25, size=int(LENGTH / 0.25))
    n = int(LENGTH / fusion.STEP_M)
    profile = fusion.grid_profile(x, rng.exponential(size=len(x)), 0.0, n)
    p = fusion.calibrate(profile, half=int(fusion.WINDOW_M / fusion.STEP_M))
    top = fusion.runs_above(-np.log(p), -np.log(0.002), 8)
    assert len(top) / (LENGTH / 1000) <= 2.0
    assert np.mean(p <= 0.01) == pytest.approx(0.01, abs=0.003)


def test_combine_is_stouffers_method() -> None:
    p = np.array([[0.01, 0.5, np.nan], [0.2, 0.5, 0.03], [0.05, np.nan, np.nan]])
    evidence, k = fusion.combine(-np.log(p))
    assert k.tolist() == [3, 2, 1]
    for j in range(3):
        q = p[:, j][np.isfinite(p[:, j])]
        expected = stats.combine_pvalues(q, method="stouffer").pvalue
        assert 10 ** -evidence[j] == pytest.approx(expected, rel=1e-9)


def places(fused: fusion.Fused, xs, scores, rate: float = 0.1) -> np.ndarray:  # type: ignore[no-untyped-def]
    runs = fusion.runs_above(fused.evidence, fused.level(rate), 8)
    return np.array([fusion.peak_position(fused, xs, scores, r) for r in runs])


def test_weak_repeating_defects_are_found_and_a_loud_stretch_is_not() -> None:
    grid = np.arange(150, 4850, 60.0)
    # Away from the loud stretch's edges: a defect within the calibration window (100 m) of a
    # louder stretch is judged against it and masked (docs/track-map.md).
    grid = grid[(grid < 1850) | (grid > 2750)]
    defects = np.sort(np.random.default_rng(1).choice(grid, 20, replace=False))
    xs, scores = profiles(8, defects, bump=2.0, loud=(2000.0, 2600.0))
    # One pass alone: a defect is rarely among its pass's highest scores (top 0.1 %).
    per_pass = [np.mean([s[np.abs(x - d) <= 1].max() > np.quantile(s, 0.999)
                         for d in defects]) for x, s in zip(xs, scores, strict=True)]
    assert max(per_pass) <= 0.2, per_pass
    fused = fusion.fuse(xs, scores)
    at = places(fused, xs, scores)
    near = np.abs(at[:, None] - defects[None, :]) <= 2.0
    assert near.any(axis=0).mean() >= 0.95
    assert (~near.any(axis=1)).sum() <= 1  # ~0.5 expected on 5 km at 0.1 per km
    assert not ((at >= 1990) & (at <= 2610)).any(), "a loud stretch of every pass was reported"


def test_the_null_estimates_the_false_rate_of_pure_noise() -> None:
    found, km = 0, 0.0
    for seed in range(4):
        xs, scores = profiles(6, np.array([]), seed=seed)
        fused = fusion.fuse(xs, scores, seed=seed)
        found += len(places(fused, xs, scores, rate=1.0))
        km += LENGTH / 1000
    assert found / km == pytest.approx(1.0, abs=0.6), (found, km)


def test_seen_on_9_of_10_is_more_evident_than_1_of_10() -> None:
    xs9, s9 = profiles(10, np.array([1000.0]), seen=list(range(9)), bump=3.0, seed=1)
    xs1, s1 = profiles(10, np.array([3000.0]), seen=[0], bump=3.0, seed=2)
    scores = [np.where(np.abs(x - 3000) <= 0.5, b, a) for x, a, b in zip(xs9, s9, s1,
                                                                      strict=True)]
    fused = fusion.fuse(xs9, scores)
    at = places(fused, xs9, scores)
    assert np.abs(at - 1000).min() <= 1.0 and not (np.abs(at - 3000) <= 2).any()
    e9 = fused.evidence[np.abs(fused.grid - 1000) <= 2].max()
    e1 = fused.evidence[np.abs(fused.grid - 3000) <= 2].max()
    assert e9 > e1 and fused.false_per_km(e9)[0] < fused.false_per_km(e1)[0]


def test_fused_map_of_a_scan_folder(tmp_path: Path) -> None:
    defects = np.array([500.0, 1800.0, 3300.0, 4400.0])
    xs, scores = profiles(6, defects, bump=4.0, seed=3)
    scan_folder(tmp_path, xs, scores, defects)
    passes = tm.read_scan(tmp_path)
    assert all(p.profile is not None for p in passes)
    locations, fused = tm.fused_map(passes)
    shown = tm.reported_fused(locations, 0.1)
    s = em.score_locations(shown, defects, LENGTH, 2.0)
    assert s["recall"] == 1.0 and s["false_per_km"] <= 0.4, s  # 0.1-0.2 per km on average
    top = locations[0]
    assert top.group == "axle" and top.channel == "axle_1" and top.passes_seen >= 5
    assert [loc.rank for loc in locations] == list(range(1, len(locations) + 1))
    assert all(a.evidence >= b.evidence for a, b in zip(locations, locations[1:], strict=False))
    out = tm.write_map(tmp_path / "map.csv", locations)
    assert out.read_text().splitlines()[0].split(",") == list(tm.MAP_FIELDS)


def test_at_field_scale_a_place_needs_an_event(tmp_path: Path) -> None:
    # A rail's texture: every pass scores higher at 2600 m, never above its event threshold.
    defects, texture = np.array([500.0, 1800.0, 3300.0, 4400.0]), np.array([2600.0])
    xs, scores = profiles(6, np.concatenate([defects, texture]), bump=4.0, seed=3)
    scan_folder(tmp_path, xs, scores, defects)  # events at the defects only

    def places(passes: list[tm.PassEvents], **kw: int) -> list[tm.Location]:
        return tm.reported_fused(tm.fused_map(passes, **kw)[0], 0.1)

    passes = tm.read_scan(tmp_path)
    assert tm.min_events_for(passes) == 0  # a scan that says no scale: the benchmark's
    assert any(abs(loc.position_m - 2600) < 2 and loc.passes_with_event == 0
               for loc in places(passes))
    for info_path in tmp_path.glob("*.scan.json"):
        info = json.loads(info_path.read_text())
        info_path.write_text(json.dumps({**info, "scale": "field"}))
    passes = tm.read_scan(tmp_path)
    assert tm.min_events_for(passes) == 1
    shown = places(passes)
    assert not any(abs(loc.position_m - 2600) < 2 for loc in shown)
    assert em.score_locations(shown, defects, LENGTH, 2.0)["recall"] == 1.0
    assert all(loc.passes_with_event >= 1 for loc in shown)
    assert any(abs(loc.position_m - 2600) < 2 for loc in places(passes, min_events=0))
    with pytest.raises(RailwatchError, match="--min-events must be 0 or more"):
        tm.fused_map(passes, min_events=-1)


def test_a_scan_without_profiles_or_with_a_damaged_one(tmp_path: Path) -> None:
    defects = np.array([500.0])
    xs, scores = profiles(2, defects, seed=4)
    scan_folder(tmp_path, xs, scores, defects)
    info = json.loads((tmp_path / "pass00.scan.json").read_text())
    del info["profile"]  # scanned when profiles kept the maximum over windows
    (tmp_path / "pass00.scan.json").write_text(json.dumps(info))
    with pytest.raises(RailwatchError, match="pass00 .*without a current score profile.*votes"):
        tm.fused_map(tm.read_scan(tmp_path))
    info["profile"] = tm.PROFILE_KIND
    (tmp_path / "pass00.scan.json").write_text(json.dumps(info))
    (tmp_path / "pass01.profile.npz").unlink()
    with pytest.raises(RailwatchError, match="pass01 .*without a current score profile.*votes"):
        tm.fused_map(tm.read_scan(tmp_path))
    assert len(tm.track_map(tm.read_scan(tmp_path))) >= 1  # the votes map needs no profile
    (tmp_path / "pass01.profile.npz").write_bytes(b"not an npz")
    with pytest.raises(RailwatchError, match="pass01.profile.npz is damaged"):
        tm.read_scan(tmp_path)


def test_one_pass_confirms_nothing() -> None:
    """Where one pass alone covered the track (near its ends), even that pass's strongest
    score is no evidence."""
    xs, scores = profiles(3, np.array([300.0, 2500.0]), bump=8.0, seed=3)
    for i in (1, 2):  # passes 1 and 2 start at 1 km
        keep = xs[i] >= 1000.0
        xs[i], scores[i] = xs[i][keep], scores[i][keep]
    fused = fusion.fuse(xs, scores, rounds=5)
    alone = (fused.grid > 50) & (fused.grid < 950)
    assert (fused.covered[alone] == 1).all() and (fused.evidence[alone] == 0).all()
    near = np.abs(fused.grid - 2500.0) <= 1.0
    assert fused.evidence[near].max() > fused.level(0.1)


def test_profile_shifts_lay_the_passes_on_each_other() -> None:
    """Passes recorded up to 3 m apart (too little for their events to move them) are laid on
    each other by their score profiles, two rounds as the track map does, to within 1 m."""
    defects = np.sort(np.random.default_rng(4).uniform(100, LENGTH - 100, 25))
    xs, scores = profiles(5, defects, bump=3.0, seed=4)
    offsets = [0.0, 3.0, -2.5, 2.0, -1.5]
    moves = [(0.0, 1.0)] * len(xs)
    for _ in range(2):
        now = [a + b * (x + off) for x, off, (a, b) in zip(xs, offsets, moves, strict=True)]
        shifts = fusion.profile_shifts(now, scores, max_scale_error=0.005)
        moves = [(a + c0 + c1 * a, b * (1 + c1))
                 for (a, b), (c0, c1) in zip(moves, shifts, strict=True)]
    # Where each pass now puts the track's start and far end, relative to the first pass.
    ends = np.array([[a + b * off, a + b * (LENGTH + off) - LENGTH]
                     for off, (a, b) in zip(offsets, moves, strict=True)])
    assert np.abs(ends - ends[0]).max() < 1.0, ends


def test_a_move_the_profiles_do_not_confirm_is_undone() -> None:
    """A pass moved 30 m (chance pairs of events) lies on the others worse than where it was
    recorded, and goes back; a pass recorded 12 m off and moved onto the others keeps its move
    (beyond the ±4 m that the segments' shifts reach)."""
    defects = np.sort(np.random.default_rng(5).uniform(100, LENGTH - 100, 25))
    xs, scores = profiles(5, defects, bump=3.0, seed=5)
    recorded = [x.copy() for x in xs]
    recorded[3] = xs[3] + 12.0  # its odometry 12 m off; the move below puts it right
    placed = [x.copy() for x in xs]
    placed[1] = xs[1] + 30.0  # a wrong move
    assert fusion.keeps_move(placed, scores, recorded) == [True, False, True, True, True]


def test_one_pass_confirms_nothing_in_a_group_the_others_lack() -> None:
    """Each sensor group needs two passes of its own: a group only one recording has gives no
    evidence, whatever the other groups' coverage."""
    xs, scores = profiles(2, np.array([2500.0]), bump=0.0, seed=5)
    two = [np.stack([s, s.copy()], axis=1) for s in scores]
    two[0][np.abs(xs[0] - 1200.0) <= 0.5, 1] = 50.0  # a lone spike in pass 0's second group
    two[1][:, 1] = np.nan  # pass 1 has no second group
    fused = fusion.fuse(xs, two, rounds=5)
    assert (fused.by_kind[1] == 0).all()
    assert (fused.covered[(fused.grid > 10) & (fused.grid < LENGTH - 10)] == 2).all()


def test_on_rails_mirrors_each_group_and_fills_missing_channels() -> None:
    score = np.array([[1.0, 2.0, 3.0]], dtype=np.float32)
    pr = tm.ScoreProfile(position=np.zeros(1), channel_score=score,
                         channels=("axle_1", "axle_2", "body_1"), groups=("axle", "axle", "body"))
    wanted = ("axle_1", "axle_2", "body_1", "bogie_1")
    assert pr.on_rails(wanted, mirrored=False)[0, :3].tolist() == [1.0, 2.0, 3.0]
    mirrored = pr.on_rails(wanted, mirrored=True)[0]
    assert mirrored[:3].tolist() == [2.0, 1.0, 3.0] and np.isnan(mirrored[3])


def sided_scan_folder(folder: Path, world: str, n: int = 6, seed: int = 7,
                      ) -> tuple[np.ndarray, np.ndarray]:
    """A scan folder of ``n`` passes, every other one down the track, over defects each felt on
    one rail: by channel axle_1 or axle_2 of a pass up the track, and of a pass down by the
    same channel (``world`` "keep": push-pull) or the other one ("swap": a turned vehicle).
    The defects' positions and rails (0: axle_1 up the track, 1: axle_2)."""
    rng = np.random.default_rng(seed)
    defects = np.sort(rng.choice(np.arange(150.0, LENGTH - 150, 100.0), 16, replace=False))
    rail = rng.integers(0, 2, len(defects))
    for i in range(n):
        up = i % 2 == 0
        x = np.arange(0, LENGTH, 0.25) + rng.uniform(0, 0.25)
        s = rng.exponential(size=(len(x), 2))
        for d, r in zip(defects, rail, strict=True):
            near = np.abs(x - d - rng.normal(0, 0.3)) <= 0.4
            channel = r if up or world == "keep" else 1 - r
            s[near, channel] += 2.0 * rng.exponential(size=near.sum()) + 2.0
        if not up:  # recorded in time order: down the track
            x, s = x[::-1], s[::-1]
        write_pass(folder, f"pass{i:02d}", x, np.arange(len(x)) / 100.0, s,
                   ("axle_1", "axle_2"), ("axle", "axle"), defects)
    return defects, rail


@pytest.mark.parametrize("world", ["swap", "keep"])
def test_auto_sides_follow_the_vehicle(tmp_path: Path, world: str) -> None:
    """Each defect on one rail: summed per channel under the vehicle's own rule it stands out on
    every pass; under the other rule on half of them; auto finds the rule from the passes."""
    defects, rail = sided_scan_folder(tmp_path, world)
    passes = tm.read_scan(tmp_path)
    recall = {}
    for sides in ("auto", "swap", "keep", "group"):
        locations, fused = tm.fused_map(passes, sides=sides)
        assert fused.sides == (world if sides == "auto" else sides)
        s = em.score_locations(tm.reported_fused(locations), defects, LENGTH)
        recall[sides] = s["recall"]
        if sides == "auto":  # each place names its rail: the channel of a pass up the map
            rails = {float(d): f"axle_{r + 1}" for d, r in zip(defects, rail, strict=True)}
            named = [(rails[d], loc.channel) for loc in tm.reported_fused(locations)
                     for d in defects if abs(loc.position_m - d) <= 2.0]
            assert len(named) >= 14 and all(a == b for a, b in named), named
    wrong = "keep" if world == "swap" else "swap"
    assert recall["auto"] == recall[world] >= 0.9 > recall[wrong] + 0.2, recall
    assert recall[world] >= recall["group"], recall


def test_track_map_names_its_sides_rule(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    from railwatch.cli import main
    from railwatch.cli.tracks import SIDES_CHOICES

    assert SIDES_CHOICES == tm.SIDES  # the CLI's copy (it loads the recordings lazily)
    sided_scan_folder(tmp_path, "keep")
    for sides, said in (("auto", "sides: keep (auto)"), ("group", "sides: group)")):
        code = main(["track-map", "--events", str(tmp_path), "--out", str(tmp_path / "m.csv"),
                     "--sides", sides])
        err = capsys.readouterr().err
        assert code == 0 and said in err, err
    code = main(["track-map", "--events", str(tmp_path), "--out", str(tmp_path / "m.csv"),
                 "--sides", "left"])
    assert code != 0 and "left" in capsys.readouterr().err


def test_track_map_min_events_is_a_number_or_auto(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    from railwatch.cli import main

    defects = np.array([1000.0, 3000.0])
    xs, scores = profiles(3, defects, bump=4.0, seed=5)
    scan_folder(tmp_path, xs, scores, defects)
    out = ["track-map", "--events", str(tmp_path), "--out", str(tmp_path / "m.csv")]
    assert main([*out, "--min-events", "2"]) == 0
    assert "an event on 2 passes at least" in capsys.readouterr().err
    assert main([*out, "--min-events", "two"]) != 0
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--min-events two: give a number" in err, err
