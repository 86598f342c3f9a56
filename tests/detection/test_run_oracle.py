"""The recordings oracle: whitening with a run's components, its noise gain, its null
threshold and its events."""

from __future__ import annotations

import numpy as np
import pytest

from railwatch.detection.oracle import (
    GUARD_S,
    REF_S,
    count_events,
    local_std,
    noise_gain,
    null_threshold,
    oracle_events,
    whitened,
)
from railwatch.detection.stream import EventTracker
from railwatch.errors import RailwatchError
from railwatch.recordings.prepare import Preparation, resample
from railwatch.synthetic.runs import synthesize_run

FS = 1000.0


@pytest.mark.parametrize(("up", "down"), [(1, 10), (1, 20), (25, 512)])
def test_noise_gain_is_the_std_of_resampled_white_noise(up: int, down: int) -> None:
    x = np.random.default_rng(0).standard_normal((300_000, 2))
    y = resample(x, up, down)[50:-50]
    assert noise_gain(up, down) == pytest.approx(float(y.std()), rel=0.02)
    assert noise_gain(1, 1) == 1.0


@pytest.mark.parametrize("seed", range(5))
def test_count_events_is_the_trackers_count(seed: int) -> None:
    rng = np.random.default_rng(seed)
    point = rng.normal(size=2000).cumsum() / 10  # runs of all lengths
    for threshold in (-1.0, 0.0, 0.5, 2.0):
        tracker = EventTracker(threshold, 7, ("a",), ("g",))
        t = np.arange(len(point), dtype=float)
        events = tracker.feed(point, point[:, None], t, None, 1.0) + tracker.close()
        assert count_events(point, threshold, 7) == len(events)


def test_whitened_run_is_unit_noise_on_quiet_and_loud_track_alike() -> None:
    """Resampled to 100 Hz, the whitened run has unit variance wherever there is no defect,
    however loud the track: the oracle knows the noise level."""
    run = synthesize_run(180.0, seed=2, fs=FS, stage=8, loud_stretches=True, components=True,
                         defect_every_s=1e6)
    assert not run.defects
    prep = Preparation()
    r = resample(whitened(run, prep), *prep.ratio(FS))[20:-20]
    np.testing.assert_allclose(r.std(axis=0), 1.0, atol=0.03)
    with pytest.raises(RailwatchError, match="components=True"):
        whitened(synthesize_run(10.0, seed=2, fs=FS), prep)


def test_null_threshold_holds_the_false_rate_on_other_noise() -> None:
    """The threshold set on one stretch of white noise gives about the asked rate on another
    (and a higher rate asks a lower threshold)."""
    prep = Preparation()
    strict, loose = (null_threshold(rate, FS, prep, minutes=20.0) for rate in (0.5, 3.0))
    assert strict > loose
    run = synthesize_run(1200.0, seed=9, fs=FS, components=True, defect_every_s=1e6)
    false = len(oracle_events(run, prep, threshold=loose)) / 20.0
    assert 1.0 < false < 6.0
    with pytest.raises(RailwatchError, match="positive"):
        null_threshold(0.0, FS)
    with pytest.raises(RailwatchError, match="'known' or 'estimated'"):
        null_threshold(1.0, FS, noise="guessed")


def test_null_threshold_of_the_estimated_level_is_its_own() -> None:
    """Noise whitened by its estimated level is not N(0, 1): the greater of two estimates
    overstates the level, so the same noise crosses a lower threshold as often."""
    known, estimated = (null_threshold(1.0, FS, minutes=20.0, noise=n)
                        for n in ("known", "estimated"))
    assert estimated < known - 0.05


def test_oracle_finds_the_defects_that_stand_out_and_names_their_channel() -> None:
    run = synthesize_run(240.0, seed=5, fs=FS, stage=8, components=True)
    events = oracle_events(run, threshold=null_threshold(1.0, FS, minutes=10.0))
    centres = np.array([d["center_s"] for d in run.defects])
    peaks = np.array([e.peak_s for e in events])
    found = [d for d in run.defects if np.any(np.abs(peaks - d["center_s"]) <= 0.25)]
    assert len(found) >= 0.9 * len(run.defects)
    false = [p for p in peaks if not np.any(np.abs(centres - p) <= 0.25)]
    assert len(false) <= 8  # 1 per minute asked, 4 minutes
    at = {round(e.peak_s, 1): e.channel for e in events}
    named = [at[k] == d["channel"] for d in found for k in at
             if abs(k - d["center_s"]) <= 0.25]
    assert np.mean(named) > 0.9


@pytest.mark.parametrize("seed", range(3))
def test_local_std_is_the_greater_side_by_brute_force(seed: int) -> None:
    fs = 100.0
    g, w = round(GUARD_S * fs), round(REF_S * fs)
    rng = np.random.default_rng(seed)
    e = rng.normal(size=(300, 2)) * rng.uniform(0.5, 3.0, size=(300, 1))
    got = local_std(e, fs)
    for i in range(300):
        sides = [e[max(0, i - g - w):max(0, i - g)], e[i + g + 1:i + g + 1 + w]]
        ms = [np.mean(side ** 2, axis=0) for side in sides if len(side)]
        np.testing.assert_allclose(got[i], np.sqrt(np.max(ms, axis=0)))


def test_estimated_noise_level_follows_a_loud_stretch_and_ignores_the_defect() -> None:
    """A detector's estimate of the level: 3x louder noise raises it 3x (so the whitened run
    stays unit noise), and a defect does not raise it at its own samples (the guard)."""
    fs = 1000.0
    rng = np.random.default_rng(0)
    gain = np.where((np.arange(20_000) > 8_000) & (np.arange(20_000) < 14_000), 3.0, 1.0)
    e = rng.standard_normal((20_000, 1)) * gain[:, None]
    e[5_000:5_200] += 4.0
    std = local_std(e, fs)[:, 0]
    assert std[10_000:12_000].mean() == pytest.approx(3.0, rel=0.05)
    assert std[5_000:5_200].max() < 1.2  # the box lies within the guard of its own samples
    assert (e[:, 0] / std)[15_000:].std() == pytest.approx(1.0, abs=0.05)
