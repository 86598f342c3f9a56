"""The physics world against published magnitudes and its own promises: static deflection under
the wheel load, the P2 and P1 bands, responses that grow with depth and speed, wheels that leave
the rail, a clean twin that differs from its pass only near the defects, the spectra's power."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from railwatch.physics.dynamics import coupled, hertz
from railwatch.physics.features import Inventory, Item, place_items
from railwatch.physics.irregularity import german_vertical, profile, roughness
from railwatch.physics.passes import PassPlan, simulate_pass
from railwatch.physics.track import TrackModel, static_profile
from railwatch.physics.vehicle import CHANNELS, Vehicle
from railwatch.physics.world import Sensors, World, build_track, grown

#: A smooth, uniform track: only the items given make the wheel move.
SMOOTH = World(length_m=400.0, irregularity=None, roughness=None, support_spread=0.0,
               voided_share=0.0, oor_um=0.0, sensors=Sensors(0.0, 0.0, 0.0))


def single(item: Item, speed: float, world: World = SMOOTH, seed: int = 1):  # type: ignore[no-untyped-def]
    """A pass at a constant ``speed`` over a track with ``item`` alone."""
    track = build_track(world, seed=0, items=([item], []) if item.kind in (
        "squat", "joint", "weld", "step", "corrugation") else ([], [item]))
    return simulate_pass(track, PassPlan(direction=1, speed_ms=(speed, speed)), seed=seed)


def squat(depth_mm: float, length_m: float = 0.06) -> Item:
    return Item(0, "squat", 200.0, length_m, depth_mm, 1)


def response(p, channel: str = "axle_left") -> float:  # type: ignore[no-untyped-def]
    """The largest departure of a pass from its clean twin on a channel (m/s²)."""
    return float(np.abs(p.columns[channel] - p.twin[channel]).max())


def test_static_deflection_under_the_wheel_load_is_a_ballasted_tracks() -> None:
    """0.5-1.5 mm on ballasted track (docs/physics.md), and within 10 % of the beam on an
    elastic foundation of the same support stiffness (Hetényi: P·β / 2k); deeper mid-bay."""
    track, load = TrackModel(), Vehicle().static_wheel_load_n
    w = static_profile(track, load)
    assert 0.5e-3 < w.mean() < 1.5e-3
    k = track.support_stiffness() / track.spacing_m
    beta = (k / (4 * track.rail_E_pa * track.rail_I_m4)) ** 0.25
    assert w.mean() == pytest.approx(load * beta / (2 * k), rel=0.1)
    assert w[len(w) // 2] > w[0]


def test_contact_force_resonates_in_the_p2_and_p1_bands() -> None:
    """The wheel on the track (P2, 30-100 Hz, Jenkins et al. 1974) and the contact spring
    between wheel and rail (P1, 0.5-1.5 kHz) are the contact force's two resonances."""
    c = coupled(Vehicle(), TrackModel(), 4000.0)
    f, force = c.freqs, np.abs(c.force_transfer[:, 0, 0])
    p2 = (f > 20) & (f < 200)
    p1 = (f > 200) & (f < 3000)
    assert 30 <= f[p2][np.argmax(force[p2])] <= 100
    assert 500 <= f[p1][np.argmax(force[p1])] <= 1500
    # At high frequency the rail and wheel stand still: the force is the contact spring's.
    assert force[-1] == pytest.approx(hertz(Vehicle()).stiffness, rel=0.3)


def test_the_contact_surrogate_follows_the_rails_receptance_where_impacts_ring() -> None:
    """The lumped rail that the contact's flights are stepped on has the finite-element rail's
    receptance over 100-3000 Hz (where an impact rings): within 35 % but near the beam's
    pinned-pinned notch (about 1.1 kHz), which a lumped model cannot have."""
    from railwatch.physics.dynamics import contact_surrogate
    from railwatch.physics.track import receptance

    f = np.geomspace(100.0, 3000.0, 40)
    _, rail = contact_surrogate(Vehicle(), TrackModel()).receptance(f)
    target, _ = receptance(TrackModel(), f)
    ratio = np.abs(rail / target)
    assert 0.9 < np.median(ratio) < 1.1
    assert np.mean((ratio > 1 / 1.35) & (ratio < 1.35)) >= 0.95


def test_response_grows_with_depth_and_speed() -> None:
    depths = [response(single(squat(d), 20.0)) for d in (0.1, 0.3, 1.0)]
    assert depths[0] < depths[1] < depths[2]
    joint = Item(0, "joint", 200.0, 0.6, 1.5, 1, (("gap_mm", 8.0), ("step_mm", 0.0)))
    passes = [single(joint, v) for v in (10.0, 20.0, 30.0)]
    assert [response(p) for p in passes] == sorted(response(p) for p in passes)
    loads = [p.peak_load for p in passes]
    assert loads == sorted(loads) and 1.2 < loads[-1] < 5.0  # a few times the static load


def test_a_wheel_leaves_the_rail_over_a_short_deep_dip_and_lands() -> None:
    deep = single(squat(1.0, 0.08), 30.0)
    assert deep.flights_m and all(190 < x < 230 for x in deep.flights_m)
    assert 2.0 < deep.peak_load < 10.0
    gentle = single(Item(0, "weld", 200.0, 1.0, 0.2, 1, (("crown_mm", 0.0), ("crown_m", 0.1))),
                    10.0)
    assert not gentle.flights_m and gentle.peak_load < 1.5


def test_the_response_is_on_the_rail_of_the_defect() -> None:
    p = single(squat(0.8, 0.07), 20.0)
    assert response(p, "axle_left") > 5 * response(p, "axle_right")
    assert response(p, "axle_left") > 10 * response(p, "body_left")


def test_a_clean_twin_differs_from_its_pass_only_near_the_defects() -> None:
    """Full physics on a short track (irregularity, roughness, supports, wheels, features),
    without sensor noise: away from where the coach's wheels crossed a defect, the pass is its
    twin; near, every defect moves its rail's axle box."""
    world = replace(World(length_m=1200.0), sensors=Sensors(0.0, 0.0, 0.0),
                    inventory=Inventory(squats_per_km=3.0, joints_per_km=1.0, welds_per_km=1.0,
                                        steps_per_km=0.0, corrugations_per_km=0.0))
    track = build_track(world, seed=3)
    for direction in (1, -1):
        p = simulate_pass(track, PassPlan(direction=direction), seed=7)
        x = p.columns["position"]
        # Every wheelset crosses within 22 m of the sensors' position; the car body rings on
        # for a few seconds more.
        for name in CHANNELS:
            reach, share = (100.0, 1e-2) if name.startswith("body") else (30.0, 1e-3)
            near = np.zeros(len(x), dtype=bool)
            for d in track.defects:
                near |= np.abs(x - d.position_m) < reach
            diff = p.columns[name] - p.twin[name]
            assert np.abs(diff[~near]).max() < share * np.abs(diff).max(), name
        for row in p.crossings:
            at = np.abs(x - row["position_m"]) < 1.0
            other = "axle_right" if row["channel"] == "axle_left" else "axle_left"
            assert np.abs(p.columns[row["channel"]] - p.twin[row["channel"]])[at].max() > \
                np.abs(p.columns[other] - p.twin[other])[at].max()


def test_sensor_noise_is_what_physics_json_says() -> None:
    world = replace(SMOOTH, sensors=Sensors(0.1, 0.02, 0.003))
    p = single(squat(0.1, 0.02), 20.0, world)
    far = np.abs(p.columns["position"] - 200.0) > 40.0
    for name, sigma in zip(CHANNELS, world.sensors.noise(), strict=True):
        noise = (p.columns[name] - p.twin[name])[far]
        assert noise.std() == pytest.approx(sigma, rel=0.1)


def test_a_pass_is_fixed_by_its_seeds() -> None:
    world = replace(World(length_m=600.0))
    a = simulate_pass(build_track(world, 2), PassPlan(direction=-1, speed_ms=(15, 25)), 4)
    b = simulate_pass(build_track(world, 2), PassPlan(direction=-1, speed_ms=(15, 25)), 4)
    for name in a.columns:
        np.testing.assert_array_equal(a.columns[name], b.columns[name])
    assert a.columns["position"][0] > a.columns["position"][-1]  # ran back
    assert 15 <= a.columns["speed"].min() and a.columns["speed"].max() <= 25


def test_a_wheel_flat_strikes_once_per_turn() -> None:
    world = replace(SMOOTH, flat_mm=0.5)
    p = single(squat(0.1, 0.02), 20.0, world)
    a = p.twin["axle_left"] - p.twin["axle_left"].mean()
    x = np.abs(p.columns["position"] - p.columns["position"][0])
    peaks = x[np.flatnonzero(a < 0.5 * a.min())]
    turns = np.diff(peaks[np.concatenate([[True], np.diff(peaks) > 1.0])])
    assert np.median(turns) == pytest.approx(2 * np.pi * world.vehicle.wheel_radius_m, rel=0.02)


@pytest.mark.parametrize("spectrum, band", [(german_vertical("high"), (1.0, 80.0)),
                                            (roughness("average"), (0.0008, 1.0))])
def test_a_profile_has_its_spectrums_power(spectrum, band) -> None:  # type: ignore[no-untyped-def]
    """The sum of cosines with random phases: the profile's variance is the spectrum's integral
    over the band (to the spread of a finite draw)."""
    dx = band[0] / 2
    length = min(4000.0, 2e6 * dx)
    omega = np.linspace(2 * np.pi / band[1], 2 * np.pi / band[0], 200_001)
    expected = np.trapezoid(spectrum(omega), omega)
    draws = [profile(spectrum, length, dx, np.random.default_rng(s), band)[1].var()
             for s in range(4)]
    assert np.mean(draws) == pytest.approx(expected, rel=0.25)


def test_items_keep_their_distance_and_sizes() -> None:
    inv = Inventory()
    defects, features = place_items(5000.0, inv, np.random.default_rng(1))
    for d in defects:  # each defect is one place on a map: min_gap_m from every other item
        for other in [*defects, *features]:
            if other is not d:
                gap = max(other.position_m - d.end_m, d.position_m - other.end_m)
                assert gap >= inv.min_gap_m - 1e-9
    squats = [d for d in defects if d.kind == "squat"]
    assert len(squats) == 12 and all(0.1 <= s.depth_mm <= 1.5 for s in squats)
    assert all(0.02 <= s.length_m <= 0.10 for s in squats)
    assert {d.kind for d in defects} == {"squat", "joint", "weld", "step", "corrugation"}
    assert {f.kind for f in features} == {"switch", "crossing", "transition", "level-crossing"}


def test_a_turnouts_crossing_nose_lies_its_lead_from_the_switch_either_way() -> None:
    """20-30 m from switch toe to crossing nose, whether the switch or the nose comes first
    along the track (until 2026-12-04 a nose-first turnout put its switch 0.3-0.5 m away)."""
    orders = set()
    for seed in range(6):
        _, features = place_items(5000.0, Inventory(turnouts_per_km=2.0),
                                  np.random.default_rng(seed))
        switches = [f for f in features if f.kind == "switch"]
        noses = [f for f in features if f.kind == "crossing"]
        assert len(switches) == len(noses) == 10
        for sw in switches:
            nose = min(noses, key=lambda n: abs(n.position_m - sw.position_m))
            assert 20.0 <= abs(nose.position_m - sw.position_m) <= 30.0
            orders.add(nose.position_m > sw.position_m)
    assert orders == {True, False}


def test_a_grown_defect_changes_the_wheel_path_near_it_only() -> None:
    """grown() rebuilds the wheel path around a changed defect from the rails before any item:
    unchanged, it gives the track's own path; deeper, a deeper path there and nothing else."""
    world = World(length_m=300.0)
    track = build_track(world, seed=2, items=([squat(0.5), Item(1, "weld", 200.2, 0.8, 0.3,
                                                                 1, (("crown_mm", 0.1),
                                                                     ("crown_m", 0.05)))],
                                              []))
    same = grown(track, track.defects)
    assert np.abs(same.path - track.path).max() < 1e-12
    deeper = grown(track, [replace(track.defects[0], depth_mm=1.0)])
    assert deeper.defects[0].depth_mm == 1.0 and deeper.clean is track.clean
    changed = np.flatnonzero(np.abs(deeper.path - track.path).max(axis=0) > 1e-9)
    at = track.x0 + 0.001 * changed
    assert at.min() > 199.7 and at.max() < 200.4
    i = int(round((200.03 - track.x0) / 0.001))
    assert deeper.path[0, i] < track.path[0, i] - 1e-4  # the rail 1 dips deeper
