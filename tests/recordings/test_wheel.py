"""The wheel comb: the turn found from the signal, the comb streamed as it is in one piece, the
impulses gone and a defect kept, and the errors."""

from __future__ import annotations

import numpy as np
import pytest

from railwatch.errors import RailwatchError
from railwatch.recordings import wheel
from railwatch.recordings.readers import Chunk

FS = 2000.0


def pass_signal(turn: float | None, speed: float = 20.0, seconds: float = 60.0, seed: int = 0,
                spike_at_m: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Distance travelled (m) and one channel: a sinusoid at 7 Hz, white noise, and with
    ``turn`` a Gaussian impulse of height 1.5 and 0.4 m every ``turn`` metres; a spike of 3.5
    over 0.2 m at ``spike_at_m``. The speed varies by ±20 % (the turn is in metres, not
    seconds)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * FS)) / FS
    v = speed * (1.0 + 0.2 * np.sin(2 * np.pi * t / 40.0))
    x = np.cumsum(v) / FS
    y = 1.0 * np.sin(2 * np.pi * 7.0 * t) + 0.3 * rng.standard_normal(len(t))
    if turn is not None:
        phase = np.mod(x, turn)
        y += 1.5 * np.exp(-np.square(phase / 0.4)) * (phase < 1.2)
    if spike_at_m is not None:
        y += 3.5 * ((x >= spike_at_m) & (x < spike_at_m + 0.2))
    return x, y


def chunks_of(x: np.ndarray, y: np.ndarray, sizes: list[int], reverse: bool = False,
              ) -> list[Chunk]:
    """Chunks with a position column (running down the track when ``reverse``)."""
    position = 5000.0 - x if reverse else 100.0 + x
    out, start = [], 0
    for n in sizes:
        part = slice(start, start + n)
        out.append(Chunk(start, y[part, None].astype(np.float32), time=None, speed=None,
                         position=position[part]))
        start += n
    return out


def test_the_turn_is_found_and_nothing_where_there_is_none() -> None:
    x, y = pass_signal(3.3)
    (turn,) = wheel.turns_of(chunks_of(x, y, [50_000] * 3), FS, 1)
    assert turn is not None
    assert abs(turn / round(turn / 3.3) - 3.3) < 0.05  # the turn or a multiple of it
    x, y = pass_signal(None)
    assert wheel.turns_of(chunks_of(x, y, [50_000] * 3), FS, 1) == [None]


@pytest.mark.parametrize("reverse", [False, True])
def test_the_streamed_comb_equals_the_comb_in_one_piece(reverse: bool) -> None:
    x, y = pass_signal(3.3, seconds=20.0)
    rng = np.random.default_rng(1)
    sizes = [int(n) for n in rng.integers(1, 3000, size=20)]
    sizes.append(len(y) - sum(sizes))
    whole = wheel.Comb([3.3], 2, FS)
    one = whole.push(chunks_of(x, y, [len(y)], reverse)[0]) + whole.close()
    parts = wheel.Comb([3.3], 2, FS)
    streamed = [c for ch in chunks_of(x, y, sizes, reverse) for c in parts.push(ch)]
    streamed += parts.close()
    a = np.concatenate([c.data for c in one])
    b = np.concatenate([c.data for c in streamed])
    assert b.shape == a.shape == (len(y), 1)
    np.testing.assert_allclose(b, a, atol=1e-5)
    # Every row comes out once, in order, with its position.
    starts = [c.start for c in streamed]
    assert starts == sorted(starts) and starts[0] == 0
    position = np.concatenate([c.position for c in streamed])
    np.testing.assert_array_equal(position, (5000.0 - x) if reverse else (100.0 + x))


def test_the_impulses_go_and_a_defect_stays() -> None:
    """The comb is linear: applied to the impulses alone they are gone, applied to a spike alone
    it stays (its echoes a quarter of it)."""
    x, y = pass_signal(3.3, spike_at_m=500.0, seconds=60.0)
    _, base = pass_signal(None, seconds=60.0)
    spike = ((x >= 500.0) & (x < 500.2)) * 3.5

    def combed(signal: np.ndarray) -> np.ndarray:
        comb = wheel.Comb([3.3], 2, FS)
        return np.concatenate([c.data[:, 0] for c in
                               comb.push(chunks_of(x, signal, [len(x)])[0]) + comb.close()])

    impulses = y - base - spike
    inside = (x > 20) & (x < x[-1] - 20)  # two turns from the ends: every turn there
    assert np.abs(impulses[inside]).max() > 1.4
    left = combed(impulses)
    # Each impulse starts with a jump, which linear interpolation smears over one sample: what
    # is left there is gone at the model's rate (a 20-sample mean: 2000 -> 100 Hz).
    assert np.percentile(np.abs(left[inside]), 99) < 0.05
    assert np.abs(np.convolve(left, np.ones(20) / 20, "same")[inside]).max() < 0.15
    out = combed(spike)
    assert out[spike > 0].min() == pytest.approx(3.5, rel=1e-3)
    assert np.abs(out[spike == 0]).max() <= 3.5 / 4 + 1e-3


def test_no_position_or_speed_is_a_one_line_error() -> None:
    with pytest.raises(RailwatchError, match="position or speed"):
        wheel.Travel(FS)(Chunk(0, np.zeros((4, 1), np.float32)))


def test_speed_alone_gives_the_distance() -> None:
    speed = np.full(10, 20.0)
    x = wheel.Travel(FS)(Chunk(0, np.zeros((10, 1), np.float32), speed=speed))
    np.testing.assert_allclose(x, np.arange(10) * 20.0 / FS)


@pytest.mark.parametrize("turns", [-1, 6, 2.0])
def test_wheel_turns_are_a_small_whole_number(turns: object) -> None:
    from railwatch.recordings.prepare import Preparation

    with pytest.raises(RailwatchError, match="whole number of turns"):
        Preparation(wheel_turns=turns).check(2000.0)  # type: ignore[arg-type]
