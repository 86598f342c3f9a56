"""The noise floor of the band the resampling drops: against a loop, block by block, and what it
follows and ignores."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railwatch.recordings.floor import NoiseFloor, noise_floor
from railwatch.recordings.prepare import Resampler


def floor_by_loop(x: np.ndarray, up: int, down: int) -> np.ndarray:
    n_out = (len(x) - 1) * up // down + 1
    sums, counts = np.zeros((n_out, x.shape[1])), np.zeros(n_out)
    for i in range(1, len(x) - 1):
        gaps = [abs(i - j * down / up) for j in range(n_out)]
        k = max(j for j in range(n_out) if gaps[j] == min(gaps))  # nearest; the later on a tie
        sums[k] += (x[i + 1] - 2 * x[i] + x[i - 1]) ** 2 / 6
        counts[k] += 1
    out = sums / np.maximum(counts, 1)[:, None]
    for k in range(n_out):  # a resampled sample no difference reached takes its neighbour's
        if counts[k] == 0:
            out[k] = out[k - 1] if k else out[k + 1]
    return out


@pytest.mark.parametrize(("up", "down"), [(1, 20), (2, 3), (5, 12)])
def test_floor_equals_a_loop(up: int, down: int) -> None:
    x = np.random.default_rng(up).standard_normal((300, 2))
    np.testing.assert_allclose(noise_floor(x, up, down), floor_by_loop(x, up, down),
                               rtol=1e-12)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(1, 90), min_size=1, max_size=20), st.sampled_from([(1, 20), (5, 12)]))
def test_blocks_of_any_size_give_the_same_floor(sizes: list[int],
                                                ratio: tuple[int, int]) -> None:
    x = np.random.default_rng(len(sizes)).standard_normal((sum(sizes) + 3, 3))
    meter, parts, i = NoiseFloor(*ratio, 3), [], 0
    for n in sizes + [3]:
        parts.append(meter.push(x[i:i + n]))
        i += n
    got = np.concatenate([*parts, meter.flush()])
    np.testing.assert_allclose(got, noise_floor(x, *ratio), rtol=1e-12)
    assert len(got) == Resampler(*ratio, 3).n_outputs(len(x))  # one per resampled sample


def test_follows_a_louder_stretch_and_ignores_the_vibration() -> None:
    """2 kHz to 100 Hz: noise 3x louder from 1 s on; a sinusoid of 25 Hz five times the noise
    and a box do not move the floor."""
    rng = np.random.default_rng(0)
    t = np.arange(4000) / 2000.0
    level = np.where(t < 1.0, 0.2, 0.6)
    noise = level * rng.standard_normal(4000)
    x = (noise + 1.0 * np.sin(2 * np.pi * 25 * t))[:, None]
    x[1500:1700] += 2.0  # a 0.1-s box
    floor = np.sqrt(noise_floor(x, 1, 20)[:, 0])
    quiet, loud = np.median(floor[5:95]), np.median(floor[105:195])
    assert 0.18 < quiet < 0.22 and 0.54 < loud < 0.66
    bare = np.sqrt(noise_floor(noise[:, None], 1, 20)[:, 0])
    assert np.median(np.abs(floor - bare) / bare) < 0.01
