"""The track map: alignment of passes, clustering, ranking, reading a scan folder."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from railwatch import trackmap as tm
from railwatch.errors import RailwatchError
from railwatch.evaluation import maps as em


def passes_over(truth: np.ndarray, n: int, seen: float, false_per_km: float, length: float,
                seed: int = 0, offsets: list[tuple[float, float]] | None = None,
                ) -> list[tm.PassEvents]:
    """Synthetic scans: each pass sees each true position with probability ``seen`` (0.3 m
    jitter), plus false events; its positions recorded as (x - a) / b."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        x = truth[rng.random(len(truth)) < seen]
        x = x + rng.normal(0, 0.3, len(x))
        false = rng.uniform(0, length, rng.poisson(false_per_km * length / 1000))
        x = np.concatenate([x, false])
        a, b = offsets[i] if offsets else (0.0, 1.0)
        rec = (x - a) / b
        out.append(tm.PassEvents(
            name=f"pass{i:02d}", position=rec, score=np.full(len(x), 5.0),
            duration_s=np.full(len(x), 0.02), channel=["axle_1"] * len(x),
            group=["axle"] * len(x), covered=tuple(sorted(((0 - a) / b, (length - a) / b)))))
    return out


def brute_clusters(x: np.ndarray, tol: float) -> set[frozenset[int]]:
    """Connected components of the graph |xi - xj| <= tol, by union-find over every pair."""
    parent = list(range(len(x)))

    def find(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    for i in range(len(x)):
        for j in range(i + 1, len(x)):
            if abs(x[i] - x[j]) <= tol:
                parent[find(i)] = find(j)
    groups: dict[int, set[int]] = {}
    for i in range(len(x)):
        groups.setdefault(find(i), set()).add(i)
    return {frozenset(g) for g in groups.values()}


@pytest.mark.parametrize("seed", range(5))
def test_single_linkage_equals_brute_force(seed: int) -> None:
    x = np.random.default_rng(seed).uniform(0, 100, 60)
    labels = tm.single_linkage(x, 2.0)
    got = {frozenset(np.flatnonzero(labels == k).tolist()) for k in np.unique(labels)}
    assert got == brute_clusters(x, 2.0)


def test_alignment_recovers_a_known_offset_and_direction() -> None:
    truth = np.sort(np.random.default_rng(1).uniform(100, 9900, 40))
    ref = truth + np.random.default_rng(2).normal(0, 0.2, 40)
    for a, b in ((37.0, 1.0), (-12.5, 1.001), (9500.0, -1.0), (9480.0, -0.999)):
        x = (truth - a) / b  # recorded so that a + b·x is the reference's position
        got_a, got_b = tm.fit_transform(x, ref, tolerance=2.0, search=None)
        assert abs(got_b - b) < 2e-4 and np.abs(got_a + got_b * x - truth).max() < 1.0


def test_a_bounded_offset_never_turns_a_pass_round() -> None:
    """With an offset bound the positions are the track's: turning a pass round would move its
    ends by the track's length, whatever it matches (here every event, turned round about its
    median); without a bound it is found."""
    truth = np.sort(np.random.default_rng(5).uniform(100, 9900, 30))
    x = 2 * np.median(truth) - truth  # the pass counted the other way
    assert tm.fit_transform(x, truth, tolerance=2.0, search=50.0)[1] > 0
    assert tm.fit_transform(x, truth, tolerance=2.0, search=None)[1] < 0


def test_nothing_moves_without_evidence() -> None:
    ref = np.array([100.0, 500.0, 900.0])
    assert tm.fit_transform(np.array([300.0, 711.0]), ref, 2.0, 50.0) == (0.0, 1.0)


def test_passes_at_their_true_positions_stay_there_among_many_false_events() -> None:
    """A few repeating events among many false ones: some slope and offset always gains a few
    chance pairs; taking it moved passes recorded at their true positions by metres."""
    truth = np.sort(np.random.default_rng(6).uniform(50, 9950, 40))
    for seed in range(3):
        passes = passes_over(truth, 5, 0.3, 5.0, 10_000, seed=seed)
        for (a, b), p in zip(tm.align(passes), passes, strict=True):
            moved = a + b * np.array(p.covered) - np.array(p.covered)
            assert np.abs(moved).max() < 1.0, (seed, p.name, a, b)


def test_one_wrong_odometer_does_not_move_the_map() -> None:
    """The map's frame is the median of the passes' odometry: one pass with a wrong wheel
    radius (0.3 %: 30 m at the far end) among five good ones leaves it where they are."""
    truth = np.sort(np.random.default_rng(7).uniform(50, 9950, 40))
    offsets = [(0.0, 1.0)] * 4 + [(0.0, 1.003)]
    passes = passes_over(truth, 5, 0.8, 1.0, 10_000, seed=1, offsets=offsets)
    for (a, b), p in zip(tm.align(passes), passes, strict=True):
        far = a + b * p.position[np.argmax(p.position)]
        x = np.sort(truth)[np.argmin(np.abs(np.sort(truth) - far))]
        assert abs(far - x) < 1.0, (p.name, a, b)


def test_the_frame_trusts_each_odometer_near_where_it_started() -> None:
    """Odometry errs by a scale error times the distance counted since the pass started:
    three passes run up the track 0.05–0.09 % long (4.5–9 m at its far end) and two run down
    it exactly. The median of all five at the far end is 5 m off; the passes that started
    there put the map within a metre of the truth at both ends."""
    truth = np.sort(np.random.default_rng(8).uniform(50, 9950, 40))
    passes = []
    for i, (direction, scale) in enumerate([(1, 1.0008), (-1, 1.0), (1, 1.0005), (-1, 1.0),
                                            (1, 1.0009)]):
        start = 0.0 if direction == 1 else 10_000.0
        rec = start + scale * (truth - start)
        passes.append(tm.PassEvents(
            name=f"pass{i:02d}", position=rec, score=np.full(len(rec), 5.0),
            duration_s=np.full(len(rec), 0.02), channel=["axle_1"] * len(rec),
            group=["axle"] * len(rec), covered=(start + scale * (0 - start),
                                                start + scale * (10_000 - start)),
            start=start))
    for (a, b), p in zip(tm.align(passes), passes, strict=True):
        assert np.abs(a + b * p.position - truth).max() < 1.0, (p.name, a, b)
    for p in passes:
        p.start = None  # without the starts, the median of all: off at the far end
    a, b = tm.align(passes)[0]
    assert np.abs(a + b * passes[0].position - truth).max() > 3.0


def test_map_of_passes_with_odometry_errors_finds_the_defects(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    truth = np.sort(np.random.default_rng(3).uniform(50, 9950, 40))
    # Offsets of 8 m and scale errors of 0.05 % (5 m at the far end), in pairs of opposite
    # sign: the map's frame (the median of the passes' odometry) is then the track's.
    a = np.random.default_rng(4).normal(0, 8, 5)
    e = np.random.default_rng(5).normal(0, 5e-4, 5)
    offsets = [(float(x), 1 + float(y)) for x, y in zip(np.r_[a, -a], np.r_[e, -e], strict=True)]
    passes = passes_over(truth, 10, 0.7, 2.0, 10_000, offsets=offsets)
    got = tm.reported(tm.track_map(passes, tolerance_m=2.0), 0.3, len(passes))
    s = em.score_locations(got, truth, 10_000, 2.0)
    assert s["recall"] >= 0.95 and s["false_per_km"] <= 0.2, s
    # Taken as recorded, offsets of 8 m scatter the passes: the alignment is what finds them.
    monkeypatch.setattr(tm.maps, "align", lambda p, *a, **k: [(0.0, 1.0)] * len(p))
    as_recorded = tm.reported(tm.track_map(passes, tolerance_m=2.0), 0.3, len(passes))
    assert em.score_locations(as_recorded, truth, 10_000, 2.0)["recall"] < 0.8


def test_seen_on_9_of_10_ranks_above_1_of_10() -> None:
    truth = np.array([1000.0, 5000.0])
    passes = passes_over(truth, 10, 1.0, 0.0, 10_000)
    for i, p in enumerate(passes):  # 5000 m: seen on pass 0 only; 1000 m: on all but pass 9
        keep = (np.abs(p.position - 5000) > 5) | (i == 0)
        keep &= (np.abs(p.position - 1000) > 5) | (i != 9)
        passes[i] = tm.PassEvents(p.name, p.position[keep], p.score[keep], p.duration_s[keep],
                                  [c for c, k in zip(p.channel, keep, strict=True) if k],
                                  [g for g, k in zip(p.group, keep, strict=True) if k],
                                  p.covered)
    locs = tm.track_map(passes, 2.0)
    by_place = {round(loc.position_m, -2): loc for loc in locs}
    nine, one = by_place[1000.0], by_place[5000.0]
    assert (nine.passes_seen, nine.passes_covered, one.passes_seen) == (9, 10, 1)
    assert nine.rank < one.rank and nine.confidence > one.confidence
    assert tm.reported(locs, 0.3, 10) == [nine]
    assert tm.wilson_lower(9, 10) > tm.wilson_lower(1, 1) > tm.wilson_lower(1, 10)


def test_reading_a_scan_folder(tmp_path: Path) -> None:
    with pytest.raises(RailwatchError, match="holds no scanned recordings"):
        tm.read_scan(tmp_path)
    (tmp_path / "a.scan.json").write_text(json.dumps(
        {"position_first_m": 0.0, "position_last_m": 100.0}))
    (tmp_path / "a.events.csv").write_text("start_s,end_s,peak_s,channel,group,score\n")
    with pytest.raises(RailwatchError, match="has no position_m column"):
        tm.read_scan(tmp_path)
    (tmp_path / "a.events.csv").write_text(
        "start_s,end_s,peak_s,channel,group,score,threshold,position_m\n"
        "1.0,1.02,1.01,axle_1,axle,7.5,3.0,42.5\n")
    (p,) = tm.read_scan(tmp_path)
    assert p.position.tolist() == [42.5] and p.covered == (0.0, 100.0)
    (tmp_path / "a.scan.json").write_text(json.dumps(
        {"position_first_m": None, "position_last_m": None}))
    with pytest.raises(RailwatchError, match="no track position"):
        tm.read_scan(tmp_path)


def test_make_map_is_the_command_s_one_call() -> None:
    """``make_map`` gives what the map functions give, names its rule, and refuses a
    ``--min-events`` that is neither a number nor auto in one line."""
    truth = np.sort(np.random.default_rng(7).uniform(50, 4950, 12))
    passes = passes_over(truth, 6, 0.8, 1.0, 5_000)
    votes = tm.maps.make_map(passes, "votes", min_share=0.3)
    direct = tm.reported(tm.track_map(passes, 2.0, 50.0), 0.3, len(passes))
    assert [p.position_m for p in votes.reported] == [p.position_m for p in direct]
    assert votes.fused is None and votes.rule == "seen on >= 0.3 of the passes that covered them"
    with pytest.raises(RailwatchError, match="--min-events some: give a number of passes"):
        tm.maps.make_map(passes, "fused", min_events="some")
