"""Long synthetic runs: the later stages' nuisance in continuous time, tied to the track."""

from __future__ import annotations

import numpy as np
import pytest

from railwatch.errors import RailwatchError
from railwatch.synthetic.runs import (
    BURST_S,
    CHANNELS,
    MEAN_SPEED,
    STRETCH_GAIN,
    synthesize_run,
)
from railwatch.synthetic.stages import P_LOCAL, P_SPIKE

MINUTES = 3.0


def run(**kw):  # type: ignore[no-untyped-def]
    return synthesize_run(MINUTES * 60, seed=4, fs=1000.0, **kw)


def test_each_stage_adds_its_component_to_the_same_run() -> None:
    s5, s6, s7, s8 = (run(stage=k) for k in (5, 6, 7, 8))
    np.testing.assert_allclose(s5.data, s6.data - _defects(s6) + _defects(s5), atol=1e-5)
    # the same defects (time, kind, size), at stage 6 on channels drawn by their kind's odds
    strip = [{k: v for k, v in d.items() if k not in ("channel", "group")} for d in s5.defects]
    assert strip == [{k: v for k, v in d.items() if k not in ("channel", "group")}
                     for d in s6.defects] == [{k: v for k, v in d.items()
                                               if k not in ("channel", "group")}
                                              for d in s8.defects]
    bursts = (s7.data - s6.data).astype(np.float64)
    share = (bursts != 0).mean()
    spacing, length = 2.0 * MEAN_SPEED, np.mean(BURST_S) * MEAN_SPEED
    assert 0.5 * length / spacing < share < 1.5 * length / spacing
    impulses = (s8.data - s7.data).astype(np.float64)
    assert (impulses >= -1e-5).all() and (impulses.max(axis=0) > 0.1).all()


def _defects(r) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The defects of run ``r`` as an array shaped like its data."""
    out = np.zeros_like(r.data)
    for d in r.defects:
        i0 = int(round(d["time_s"] * r.fs))
        i1 = max(i0 + 1, int(round((d["time_s"] + d["duration_s"]) * r.fs)))
        out[i0:i1, CHANNELS.index(d["channel"])] += d["offset"]
    return out


def test_impulses_repeat_at_a_fixed_distance_of_travel() -> None:
    """Wheel-periodic: one impulse every L metres whatever the speed, so every L / v seconds."""
    s7, s8 = run(stage=7), run(stage=8)
    imp = (s8.data - s7.data)[:, 0].astype(np.float64)
    starts = np.flatnonzero((imp[1:] > 1e-6) & (imp[:-1] <= 1e-6)) + 1
    gaps = np.diff(s8.position[starts])
    assert len(gaps) > 100
    np.testing.assert_allclose(gaps, np.median(gaps), rtol=0.02)
    assert np.ptp(np.diff(s8.time[starts])) > 0.02  # while the period in time changes


def test_loud_stretches_raise_the_noise_of_whole_sections_of_track() -> None:
    quiet, loud = run(), run(loud_stretches=True)
    extra = (loud.data - quiet.data).astype(np.float64)  # (gain - 1) * noise
    rough = np.abs(extra).max(axis=1) > 0
    assert 0.15 < rough.mean() < 0.7  # 4 sections in 10 on average
    # every channel at once, over stretches of at least 200 m
    edges = np.flatnonzero(np.diff(rough.astype(int)))
    lengths = np.diff(loud.position[edges])[::2] if rough[0] == 0 else np.diff(
        loud.position[edges])[1::2]
    assert (lengths[1:-1] >= 199.0).all()
    sec = rough & (np.abs(extra).min(axis=1) > 0)
    gain = 1 + np.median(np.abs(extra[sec]), axis=0) / np.median(
        np.abs(_noise_only(quiet)[sec]), axis=0)
    assert (gain > STRETCH_GAIN[0] * 0.8).all() and (gain < STRETCH_GAIN[1] * 1.2).all()


def _noise_only(r) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The white noise of a stage-5 run: the run minus its stage-5 run without noise is not
    available, so take a high-pass estimate (the sinusoids are below 25 Hz at 1000 Hz)."""
    x = r.data.astype(np.float64) - _defects(r)
    return np.diff(x, axis=0, prepend=x[:1]) / np.sqrt(2.0)


def test_stage_6_draws_defect_channels_by_kind() -> None:
    r = synthesize_run(1200.0, seed=1, fs=200.0, defect_every_s=2.0, stage=6)
    for kind, odds in (("spike", P_SPIKE), ("deviation", P_LOCAL)):
        chans = [CHANNELS.index(d["channel"]) for d in r.defects if d["kind"] == kind]
        share = np.bincount(chans, minlength=6) / len(chans)
        np.testing.assert_allclose(share, odds, atol=0.06)


def test_a_stage_a_run_cannot_carry_is_one_line() -> None:
    with pytest.raises(RailwatchError, match="stage 5, 6, 7 or 8"):
        synthesize_run(10.0, stage=4)


def test_components_are_the_run_without_its_white_noise_and_defects() -> None:
    """``components=True`` keeps the data as they were and adds what the oracle needs: the data
    less the nuisance and the defects is white noise of the kept std, louder on loud track."""
    plain = run(stage=8, loud_stretches=True)
    r = run(stage=8, loud_stretches=True, components=True)
    assert plain.nuisance is None and plain.noise_std is None
    np.testing.assert_array_equal(r.data, plain.data)
    z = (r.data.astype(np.float64) - r.nuisance - _defects(r)) / r.noise_std
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=0.02)
    np.testing.assert_allclose(z.std(axis=0), 1.0, atol=0.02)
    # the nuisance holds the impulses (stage 8) and the std the loud stretches
    assert np.abs(r.nuisance - run(stage=7, components=True).nuisance).max() > 0.1
    quiet = run(stage=8, components=True)
    ratio = r.noise_std / quiet.noise_std
    assert ratio.min() >= 1.0 - 1e-6 and STRETCH_GAIN[0] - 1e-6 <= ratio.max() <= STRETCH_GAIN[1]


def test_a_run_made_differently_changes_what_it_says_and_nothing_else() -> None:
    """:class:`Variation`: the default is the run as made; each variation changes its own part
    (the same seed keeps the rest: defects' times and sizes, the noise)."""
    from railwatch.synthetic.runs import Variation, deviation

    base = run(components=True)
    same = run(components=True, variation=Variation())
    np.testing.assert_array_equal(base.data, same.data)
    # harmonics: another vibration, the same noise and defects
    harm = run(components=True, variation=Variation(harmonics=(0.5, 0.25)))
    np.testing.assert_allclose(harm.data - harm.nuisance, base.data - base.nuisance, atol=1e-5)
    spectrum = np.abs(np.fft.rfft(harm.nuisance[:, 4] - base.nuisance[:, 4]))
    assert spectrum.max() > 0.1 * np.abs(np.fft.rfft(base.nuisance[:, 4])).max()
    # shapes: a triangle peaks at the box's offset and holds half its sum
    tri = run(variation=Variation(deviation_shape="triangle"))
    assert [d["time_s"] for d in tri.defects] == [d["time_s"] for d in base.defects]
    np.testing.assert_allclose(deviation("triangle", 100).sum() / 100, 0.5, atol=0.01)
    np.testing.assert_allclose(deviation("half-sine", 1000).mean(), 2 / np.pi, atol=0.01)
    box = next(d for d in base.defects if d["kind"] == "deviation")
    i0 = int(round(box["time_s"] * 1000.0))
    n = max(1, int(round((box["time_s"] + box["duration_s"]) * 1000.0)) - i0)
    c = CHANNELS.index(box["channel"])
    diff = (tri.data - base.data)[i0:i0 + n, c]
    np.testing.assert_allclose(diff, box["offset"] * (deviation("triangle", n) - 1), atol=1e-5)
    # the noise level ramps from one level to the next: no step between neighbouring samples
    ramps = run(components=True, variation=Variation(noise_ramps=True)).noise_std[:, 0]
    steps = base.noise_std[:, 0]
    assert np.abs(np.diff(steps)).max() > 0.05 > np.abs(np.diff(ramps)).max()
    # the speed: knots every 5 s over a wider range
    fast = run(variation=Variation(speed_knot_s=5.0, speed_range=(5.0, 35.0)))
    assert fast.speed.min() < 15.0 or fast.speed.max() > 30.0
    assert np.abs(np.diff(fast.speed)).max() * 1000.0 > np.abs(np.diff(base.speed)).max() * 1000.0
    with pytest.raises(RailwatchError, match="deviation_shape must be one of box"):
        Variation(deviation_shape="dome")
    with pytest.raises(RailwatchError, match="speed_knot_s > 0"):
        Variation(speed_knot_s=0.0)
