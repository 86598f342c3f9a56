"""Resampling and windowing of recordings."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railwatch.errors import RailwatchError
from railwatch.recordings.prepare import Decimator, Preparation, decimate, frame, n_windows


def test_resampling_keeps_5_hz_and_removes_content_above_the_new_nyquist() -> None:
    t = np.arange(0, 20, 1 / 2000)
    x = np.stack([np.sin(2 * np.pi * 5 * t), np.sin(2 * np.pi * 70 * t),
                  np.sin(2 * np.pi * 5 * t) + np.sin(2 * np.pi * 300 * t)], axis=1)
    y = decimate(x, 20)  # 2000 -> 100 Hz: Nyquist 50 Hz
    assert y.shape == (2000, 3)
    inner = slice(100, -100)  # away from the edges
    t100 = np.arange(2000) / 100
    np.testing.assert_allclose(y[inner, 0], np.sin(2 * np.pi * 5 * t100)[inner], atol=2e-3)
    assert np.abs(y[inner, 1]).max() < 1e-3  # 70 Hz would alias to 30 Hz: removed
    np.testing.assert_allclose(y[inner, 2], y[inner, 0], atol=1e-3)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 400), min_size=1, max_size=20), st.sampled_from([2, 5, 20]))
def test_streaming_equals_one_shot(sizes: list[int], q: int) -> None:
    rng = np.random.default_rng(sum(sizes))
    x = rng.normal(size=(sum(sizes), 2))
    d = Decimator(q, 2)
    parts, i = [], 0
    for n in sizes:
        parts.append(d.push(x[i:i + n]))
        i += n
    parts.append(d.flush())
    np.testing.assert_array_equal(np.concatenate(parts), decimate(x, q))
    assert len(np.concatenate(parts)) == -(-len(x) // q)


def test_one_shot_equals_convolution_with_edges_repeated() -> None:
    from railwatch.recordings.prepare import antialias_filter

    rng = np.random.default_rng(1)
    x = rng.normal(size=(1001, 1))
    h = antialias_filter(5)
    d = (len(h) - 1) // 2
    padded = np.r_[np.repeat(x[:1, 0], d), x[:, 0], np.repeat(x[-1:, 0], d)]
    ref = np.convolve(padded, h, mode="valid")[::5]
    np.testing.assert_allclose(decimate(x, 5)[:, 0], ref, atol=1e-12)


def test_preparation_factor_and_errors() -> None:
    assert Preparation().factor(2000.0) == 20
    assert Preparation(rate=None).factor(2048.0) == 1
    with pytest.raises(RailwatchError, match="integer multiple"):
        Preparation(rate=100).factor(2048.0)
    with pytest.raises(RailwatchError, match="integer multiple"):
        Preparation(rate=200).factor(100.0)


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
