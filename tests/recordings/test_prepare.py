"""Resampling and windowing of recordings."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railwatch.errors import RailwatchError
from railwatch.recordings.prepare import (
    FIELD_WINDOW_M,
    FIELD_WINDOW_S,
    Preparation,
    Resampler,
    antialias_filter,
    choose,
    frame,
    n_windows,
    resample,
)


@pytest.mark.parametrize(("fs", "up", "down"), [(2000.0, 1, 20), (2048.0, 25, 512)])
def test_resampling_keeps_5_hz_and_removes_content_above_the_new_nyquist(
        fs: float, up: int, down: int) -> None:
    assert Preparation().ratio(fs) == (up, down)
    t = np.arange(0, 20, 1 / fs)
    x = np.stack([np.sin(2 * np.pi * 5 * t), np.sin(2 * np.pi * 70 * t),
                  np.sin(2 * np.pi * 5 * t) + np.sin(2 * np.pi * 300 * t)], axis=1)
    y = resample(x, up, down)  # -> 100 Hz: Nyquist 50 Hz
    assert y.shape == (2000, 3)
    inner = slice(100, -100)  # away from the edges
    t100 = np.arange(2000) / 100
    np.testing.assert_allclose(y[inner, 0], np.sin(2 * np.pi * 5 * t100)[inner], atol=2e-3)
    assert np.abs(y[inner, 1]).max() < 1e-3  # 70 Hz would alias to 30 Hz: removed
    np.testing.assert_allclose(y[inner, 2], y[inner, 0], atol=1e-3)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 400), min_size=1, max_size=20),
       st.sampled_from([(1, 2), (1, 5), (1, 20), (2, 3), (5, 12), (25, 512)]))
def test_streaming_equals_one_shot(sizes: list[int], ratio: tuple[int, int]) -> None:
    up, down = ratio
    rng = np.random.default_rng(sum(sizes))
    x = rng.normal(size=(sum(sizes), 2))
    r = Resampler(up, down, 2)
    parts, i = [], 0
    for n in sizes:
        parts.append(r.push(x[i:i + n]))
        i += n
    parts.append(r.flush())
    np.testing.assert_array_equal(np.concatenate(parts), resample(x, up, down))
    assert len(np.concatenate(parts)) == (len(x) - 1) * up // down + 1


@pytest.mark.parametrize(("up", "down"), [(1, 5), (2, 3), (5, 12)])
def test_one_shot_equals_the_definition_with_edges_repeated(up: int, down: int) -> None:
    """y[k] = Σ_n h[k·down + D − n·up] x[n], x extended by repetition at both ends."""
    rng = np.random.default_rng(1)
    x = rng.normal(size=(301, 1))
    h = antialias_filter(up, down)
    delay = (len(h) - 1) // 2
    n_out = (len(x) - 1) * up // down + 1
    ref = np.zeros(n_out)
    for k in range(n_out):
        for n in range(-len(h), len(x) + len(h)):
            j = k * down + delay - n * up
            if 0 <= j < len(h):
                ref[k] += h[j] * x[min(max(n, 0), len(x) - 1), 0]
    np.testing.assert_allclose(resample(x, up, down)[:, 0], ref, atol=1e-6)


@pytest.mark.parametrize(("up", "down", "n_in"), [(1, 20, 4001), (1, 20, 4019), (2, 3, 301),
                                                  (5, 12, 700), (125, 128, 3000), (1, 1, 50)])
def test_clean_outputs_read_only_the_recording(up: int, down: int, n_in: int) -> None:
    """The outputs whose filter taps all fall on input samples 0 .. n_in − 1."""
    r = Resampler(up, down, 1)
    h = antialias_filter(up, down) if (up, down) != (1, 1) else np.ones(1)
    delay = (len(h) - 1) // 2
    clean = []
    for k in range(r.n_outputs(n_in)):  # n with 0 <= k·down + D − n·up < len(h)
        lo, hi = -(-(k * down + delay - len(h) + 1) // up), (k * down + delay) // up
        if lo >= 0 and hi <= n_in - 1:
            clean.append(k)
    first, stop = r.clean(n_in)
    assert list(range(first, stop)) == clean


def test_preparation_ratio_and_errors() -> None:
    assert Preparation().ratio(2000.0) == (1, 20)
    assert Preparation().ratio(25600.0) == (1, 256)
    assert Preparation(rate=None).ratio(2048.0) == (1, 1)
    with pytest.raises(RailwatchError, match="only lowers the rate"):
        Preparation(rate=200).ratio(100.0)
    with pytest.raises(RailwatchError, match="not a fraction"):
        Preparation(rate=100).ratio(1651.7)


@given(st.integers(1, 60), st.integers(1, 12), st.integers(1, 12))
def test_frame_covers_every_sample(n_extra: int, window: int, hop: int) -> None:
    n, hop = window + n_extra, min(hop, window)  # a hop longer than the window leaves gaps
    x = np.arange(n, dtype=float)[:, None]
    w, starts = frame(x, window, hop)
    assert len(w) == n_windows(n, window, hop) == len(starts)
    covered = np.zeros(n, bool)
    for s, win in zip(starts, w, strict=True):
        np.testing.assert_array_equal(win[:, 0], x[s:s + window, 0])
        covered[s:s + window] = True
    assert covered.all()
    with pytest.raises(RailwatchError, match="shorter than one window"):
        frame(x[:window - 1] if window > 1 else x[:0], window, hop)


GROUPS = ("axle", "axle", "bogie", "bogie", "body", "body")


def test_field_scale_keeps_the_rate_and_scores_the_axle_boxes() -> None:
    """A real rail: a 2-10 cm squat lasts 1-10 ms, so the file's rate is kept; a window covers
    10 m of track at the median speed (clipped to 0.25-2 s); the axle boxes are scored."""
    c = choose(GROUPS, "field", 2000.0, median_speed=20.0)
    assert c.preparation.rate is None and c.groups == ("axle",)
    assert c.preparation.window_s == pytest.approx(FIELD_WINDOW_M / 20.0)
    assert c.preparation.detect_hop_s == c.preparation.window_s
    assert c.preparation.train_hop_s == pytest.approx(c.preparation.window_s / 2)
    assert any("behind the suspension" in r for r in c.reasons)
    assert choose(GROUPS, "field", 2000.0, 2.0).preparation.window_s == FIELD_WINDOW_S[1]
    assert choose(GROUPS, "field", 2000.0, 80.0).preparation.window_s == FIELD_WINDOW_S[0]
    assert choose(GROUPS, "field", 2000.0, None).preparation.window_s == 0.5
    # The window is a whole number of samples at the rate it is scored at.
    assert choose(GROUPS, "field", 2048.0, 23.0).preparation.window_s * 2048 % 1 == \
        pytest.approx(0.0, abs=1e-9)


def test_benchmark_scale_is_the_papers_preparation() -> None:
    c = choose(GROUPS, "benchmark", 2000.0, median_speed=22.5)
    assert c.preparation == Preparation() and c.groups == ("axle", "bogie", "body")


def test_choices_can_be_overridden_and_say_plainly_what_to_choose() -> None:
    c = choose(GROUPS, "field", 2000.0, 20.0, rate=1000.0, window_s=1.0, hop_s=0.25,
               chosen_groups=("axle", "bogie"))
    assert (c.preparation.rate, c.preparation.window_s, c.preparation.train_hop_s) == \
        (1000.0, 1.0, 0.25)
    assert c.groups == ("axle", "bogie")
    sensors = choose(("sensor",) * 3, "field", 1000.0, 15.0)
    assert sensors.groups == ("sensor",) and any("--groups" in r for r in sensors.reasons)
    with pytest.raises(RailwatchError, match="--groups wheel"):
        choose(GROUPS, "field", 2000.0, 20.0, chosen_groups=("wheel",))
