"""The map's weld layer: the Gumbel level of the line's own texture, the median over passes, the
rails of a vehicle turned at the ends, and its places in the map beside the event layer's."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from railwatch import trackmap as tm
from railwatch.trackmap import welds
from railwatch.trackmap.maps import make_map
from support import profiles, write_pass

LENGTH = 5_000.0


def test_the_gumbel_fit_recovers_its_law_and_the_level_inverts_the_rate() -> None:
    sample = stats.gumbel_r.rvs(loc=3.2, scale=0.4, size=20_000, random_state=0)
    mu, beta = welds.gumbel_fit(sample)
    assert mu == pytest.approx(3.2, abs=0.03) and beta == pytest.approx(0.4, rel=0.05)
    layer = welds.WeldLayer(grid=np.zeros(2), fused=np.zeros((2, 2)), per_pass=np.zeros((1, 2)),
                            passes=(0,), covered=np.zeros(2, dtype=np.int64), mu=mu, beta=beta,
                            channels=("axle_left", "axle_right"))
    for per_km in (0.01, 0.1, 1.0):
        assert layer.false_per_km(layer.level(per_km))[0] == pytest.approx(per_km, rel=1e-9)
    # 0.1 places per km are one 10-m stretch in 10,000: the law's quantile there.
    assert layer.level(0.1) == pytest.approx(stats.gumbel_r.ppf(1 - 1e-3, mu, beta))


def weld_tests(n: int, texture: dict[float, float], once: dict[float, float],
               seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each pass's weld test every 5 cm (z of the rails' texture: the bank's highest of a few
    N(0, 1) tests, about 1.9 in the median), plus ``texture`` (position -> z on rail 1 of every
    pass: a weld) and ``once`` (on the first pass only)."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        x = np.arange(0.0, LENGTH, 0.05) + rng.uniform(0, 0.05)
        z = np.maximum(rng.normal(0, 1, (len(x), 2)), rng.normal(0, 1, (len(x), 2))) + 1.3
        z = np.maximum.reduce([z, *(rng.normal(0, 1, (len(x), 2)) + 1.3 for _ in range(3))])
        for at, value in {**texture, **(once if i == 0 else {})}.items():
            z[np.abs(x - at) < 0.3, 0] = value + rng.normal(0, 0.3)
        out.append((x, z))
    return out


def test_a_weld_on_every_pass_is_a_place_and_one_pass_alone_is_not(tmp_path: Path) -> None:
    defects = np.array([500.0, 3300.0])
    xs, scores = profiles(6, defects, bump=4.0, seed=3)
    tests = weld_tests(6, texture={2600.0: 9.0, 3300.0: 7.0}, once={4100.0: 14.0})
    for i, (x, s) in enumerate(zip(xs, scores, strict=True)):
        write_pass(tmp_path, f"pass{i:02d}", x, x / 20.0, np.stack([s, 0.5 * s], axis=1),
                   ("axle_left", "axle_right"), ("axle", "axle"), defects, weld=tests[i])
    made = make_map(tm.read_scan(tmp_path), sides="keep")
    assert made.fused is not None and made.fused.welds is not None
    assert made.fused.welds.level(0.1) == pytest.approx(5.5, abs=1.0)
    by_place = {round(p.position_m / 100): p for p in made.reported}
    weld = by_place[26]  # the weld: a place of its own, on the rail of axle_left
    assert weld.group == "rail height" and weld.kind_guess == "weld-like"
    assert weld.weld_z == pytest.approx(9.0, abs=1.0) and weld.channel == "axle_left"
    assert weld.passes_seen == 6 and weld.false_per_km < 1e-6
    assert 41 not in by_place  # one pass alone: the median of six passes does not see it
    assert by_place[33].group == "axle" and by_place[33].weld_z == pytest.approx(7.0, abs=1.0)
    assert np.isfinite(by_place[5].weld_z) and by_place[5].weld_z < 5.5
    assert [p.rank for p in made.places] == list(range(1, len(made.places) + 1))
    # The weld layer reports the weld alone: no place of the texture.
    only = [p.position_m for p in made.reported if p.group == "rail height"]
    assert len(only) == 1 and only[0] == pytest.approx(2600.0, abs=2.0)


def test_a_weld_on_a_weak_event_place_reports_it(tmp_path: Path) -> None:
    """An event-layer place listed but not reported (its evidence below the level) is reported
    when the weld layer finds a weld on it: either layer's report counts."""
    defects = np.array([500.0, 3300.0])
    xs, scores = profiles(6, defects, bump=4.0, seed=3)
    rng = np.random.default_rng(7)
    for x, s in zip(xs, scores, strict=True):  # a weak rise at 4400 m on every pass
        near = np.abs(x - 4400.0) <= 0.4
        s[near] += 0.8 + 0.8 * rng.exponential(size=near.sum())
    tests = weld_tests(6, texture={4400.0: 9.0}, once={})
    for i, (x, s) in enumerate(zip(xs, scores, strict=True)):
        write_pass(tmp_path, f"pass{i:02d}", x, x / 20.0, np.stack([s, 0.5 * s], axis=1),
                   ("axle_left", "axle_right"), ("axle", "axle"),
                   np.array([500.0, 3300.0, 4400.0]), weld=tests[i])
    passes = tm.read_scan(tmp_path)
    events_only = make_map([replace(p, profile=replace(p.profile, weld_z=None))
                            for p in passes if p.profile is not None], sides="keep")
    weak = [p for p in events_only.places if abs(p.position_m - 4400.0) < 3.0]
    assert weak and weak[0].false_per_km > 0.1  # listed, not reported, without the weld test
    made = make_map(passes, sides="keep")
    place = [p for p in made.reported if abs(p.position_m - 4400.0) < 3.0]
    assert len(place) == 1 and place[0].group == "axle" and place[0].false_per_km < 1e-6
    assert place[0].weld_z == pytest.approx(9.0, abs=1.0)


def test_a_strong_dips_sidelobe_is_no_place_and_a_weld_beyond_it_is(tmp_path: Path) -> None:
    """A step (z 80 on every pass) rings at z 6.5 six metres on; 45 m on, a weld (z 8)."""
    defects = np.array([500.0, 3300.0])
    xs, scores = profiles(6, defects, bump=4.0, seed=3)
    tests = weld_tests(6, texture={1500.0: 80.0, 1506.0: 6.5, 1545.0: 8.0}, once={})
    for i, (x, s) in enumerate(zip(xs, scores, strict=True)):
        write_pass(tmp_path, f"pass{i:02d}", x, x / 20.0, np.stack([s, 0.5 * s], axis=1),
                   ("axle_left", "axle_right"), ("axle", "axle"), defects, weld=tests[i])
    made = make_map(tm.read_scan(tmp_path), sides="keep")
    at = sorted(p.position_m for p in made.reported if p.group == "rail height")
    assert at == pytest.approx([1500.0, 1545.0], abs=2.0)  # the step (no event there) and the
    # weld; not the sidelobe


def test_a_vehicle_turned_at_the_ends_puts_each_axle_box_on_its_rail(tmp_path: Path) -> None:
    """Passes down the map have their axle boxes on the other rails (sides: swap): the weld is
    on one rail of the track, seen by axle_left up the map and by axle_right down it."""
    defects = np.array([500.0, 3300.0])
    xs, scores = profiles(6, defects, bump=4.0, seed=4)
    tests = weld_tests(6, texture={2600.0: 9.0}, once={}, seed=5)
    for i, (x, s) in enumerate(zip(xs, scores, strict=True)):
        x_w, z = tests[i]
        if i % 2:  # down the map: in time order, and the weld under the right axle box
            x, s, x_w, z = x[::-1], s[::-1], x_w[::-1], z[::-1, ::-1]
        write_pass(tmp_path, f"pass{i:02d}", x, np.arange(len(x)) * 0.0125,
                   np.stack([s, 0.5 * s], axis=1), ("axle_left", "axle_right"),
                   ("axle", "axle"), defects, weld=(x_w, z))
    swapped = make_map(tm.read_scan(tmp_path), sides="swap")
    kept = make_map(tm.read_scan(tmp_path), sides="keep")
    assert swapped.fused is not None and kept.fused is not None
    lay_s, lay_k = swapped.fused.welds, kept.fused.welds
    at = np.argmin(np.abs(lay_s.grid - 2600.0))
    assert lay_s.fused[0, at - 8:at + 8].max() > 8.0  # the weld's rail: all six passes
    assert lay_k.fused[:, at - 8:at + 8].max() < 8.0  # each rail: three passes of six


def test_without_a_weld_test_the_map_is_as_before(tmp_path: Path) -> None:
    defects = np.array([500.0, 3300.0])
    xs, scores = profiles(4, defects, bump=4.0, seed=3)
    for i, (x, s) in enumerate(zip(xs, scores, strict=True)):
        write_pass(tmp_path, f"pass{i:02d}", x, x / 20.0, np.stack([s, 0.5 * s], axis=1),
                   ("axle_left", "axle_right"), ("axle", "axle"), defects)
    made = make_map(tm.read_scan(tmp_path))
    assert made.fused is not None and made.fused.welds is None
    assert all(np.isnan(p.weld_z) and p.group == "axle" for p in made.places)


def test_a_stretch_whose_texture_spreads_wider_on_every_pass_is_judged_against_itself(
        tmp_path: Path) -> None:
    """Where every pass's weld test spreads five times wider about its median over 300 m (a
    stretch run at another speed than the pass's spectra say), its peaks are no places; a
    weld on quiet track still is, at its z. Without the stretch's own spread (SPREAD_M = 0)
    they are places."""
    defects = np.array([500.0, 3300.0])
    xs, scores = profiles(6, defects, bump=4.0, seed=3)
    tests = weld_tests(6, texture={2600.0: 9.0}, once={})
    for i, (x, s) in enumerate(zip(xs, scores, strict=True)):
        x_w, z = tests[i]
        wide = (x_w > 1000.0) & (x_w < 1300.0)
        middle = np.median(z, axis=0)
        z[wide] = middle + 5.0 * (z[wide] - middle)
        write_pass(tmp_path, f"pass{i:02d}", x, x / 20.0, np.stack([s, 0.5 * s], axis=1),
                   ("axle_left", "axle_right"), ("axle", "axle"), defects, weld=(x_w, z))
    made = make_map(tm.read_scan(tmp_path), sides="keep")
    only = [p.position_m for p in made.reported if p.group == "rail height"]
    assert len(only) == 1 and only[0] == pytest.approx(2600.0, abs=2.0)
    assert made.fused is not None and made.fused.welds is not None
    weld = next(p for p in made.reported if p.group == "rail height")
    assert weld.weld_z == pytest.approx(9.0, abs=1.0)

    welds.SPREAD_M, kept = 0.0, welds.SPREAD_M
    try:
        blind = make_map(tm.read_scan(tmp_path), sides="keep")
    finally:
        welds.SPREAD_M = kept
    assert any(1000.0 < p.position_m < 1300.0 for p in blind.reported
               if p.group == "rail height")


def test_deflated_leaves_an_even_pass_alone_and_divides_a_wide_stretch() -> None:
    rng = np.random.default_rng(1)
    x = np.arange(0.0, 2000.0, 0.05)
    z = rng.normal(0, 1, len(x)) + 1.5
    z[len(x) // 2] = 12.0  # a weld: one peak does not move its stretch's quartiles
    assert np.array_equal(welds.deflated(z, x)[np.abs(x - 1000.0) < 0.1],
                          z[np.abs(x - 1000.0) < 0.1])
    wide = z.copy()
    inside = (x > 200.0) & (x < 500.0)
    wide[inside] = 1.5 + 6.0 * (wide[inside] - 1.5)
    out = welds.deflated(wide, x)
    core = (x > 260.0) & (x < 440.0)
    spread = [np.percentile(v[core], 75) - np.median(v[core]) for v in (z, wide, out)]
    assert spread[1] == pytest.approx(6.0 * spread[0], rel=0.05)
    assert spread[2] == pytest.approx(spread[0], rel=0.15)  # drawn in by 6
    far = x > 600.0  # at most a little: a quiet stretch's spread is near the pass's own
    assert np.all(np.abs(out[far] - 1.5) >= 0.85 * np.abs(wide[far] - 1.5) - 0.05)
    x_nan = x.copy()
    assert np.isnan(welds.deflated(np.full(len(x), np.nan), x_nan)).all()
