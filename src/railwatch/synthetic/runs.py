"""Long synthetic runs at the field rate: test recordings for the recordings pipeline.

A *run* is one continuous six-channel recording (axle ×2, bogie ×2, body ×2) at 2000 Hz by default,
with a speed profile, a track position, and defects at known times and positions. It carries the
Stage-5 signal into continuous time (``docs/recordings.md`` gives the choices):

- each channel is a sinusoid with its group's Stage-5 ranges of frequency f and amplitude A; the
  train's speed v(t) (piecewise linear between knots every 30 s, U[15, 30] m/s) scales both by
  v / 22.5 m/s, as Stage 2's speed change scales them by k_f and k_A (phase continuous,
  φ ~ U[0, 2π]);
- white noise whose std changes along the run, as Stage 4's noise step does inside a window: a
  new level σ + Δσ·b (σ, Δσ ~ U[0.1, 0.5], b ∈ {0, 1}) every U[0.4, 1.6] s, drawn per channel;
- defects, one every ``defect_every_s`` on average (Poisson, at least 2 s apart), on one channel
  each, uniformly: half spikes (0.01 s long, the field-rate spike; offset ±U[3, 4] by default) and
  half local deviations (U[0.05, 0.2] s, offset ±U[1.5, 2]) — the upper halves of the benchmark's
  sizes.

As in the generator's field-rate mode, parameters are per sample whatever the rate, so decimating a
2000 Hz run to 100 Hz also lowers the white noise by √20.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.errors import RailwatchError
from railwatch.recordings.layout import Layout
from railwatch.synthetic.stages import GROUPS

CHANNELS = ("axle_1", "axle_2", "bogie_1", "bogie_2", "body_1", "body_2")
CHANNEL_GROUPS = ("axle", "axle", "bogie", "bogie", "body", "body")
MEAN_SPEED = 22.5  # m/s: speed at which f and A are the drawn values


#: Columns of the true-defects table (one row per defect).
DEFECT_FIELDS = ("time_s", "duration_s", "center_s", "position_m", "channel", "group", "kind",
                 "offset")


@dataclass
class Run:
    fs: float
    data: NDArray[np.float32]  # (n, 6)
    time: NDArray[np.float64]  # (n,) s
    speed: NDArray[np.float64]  # (n,) m/s
    position: NDArray[np.float64]  # (n,) m
    defects: list[dict[str, Any]] = field(default_factory=list)

    def columns(self) -> dict[str, NDArray[Any]]:
        """The run as named columns: time, speed, position, then the six channels."""
        cols: dict[str, NDArray[Any]] = {"time": self.time, "speed": self.speed,
                                         "position": self.position}
        cols.update({c: self.data[:, i] for i, c in enumerate(CHANNELS)})
        return cols

    @staticmethod
    def layout(fs: float = 2000.0, with_position: bool = True) -> Layout:
        """The layout of :meth:`columns` written to a file."""
        return Layout(fs=fs, channels=CHANNELS, groups=CHANNEL_GROUPS, time="time",
                      speed="speed", position="position" if with_position else None)


def synthesize_run(
    duration_s: float = 600.0,
    seed: int = 0,
    fs: float = 2000.0,
    defect_every_s: float = 10.0,
    spike_offset: tuple[float, float] = (3.0, 4.0),
    deviation_offset: tuple[float, float] = (1.5, 2.0),
) -> Run:
    """A continuous six-channel run with defects at known times; see the module docstring."""
    if fs < 100.0:
        raise RailwatchError(f"a run needs fs >= 100 Hz (a spike lasts 0.01 s), got {fs:g}")
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * fs))
    t = np.arange(n) / fs

    knots_t = np.arange(0.0, duration_s + 30.0, 30.0)
    speed = np.interp(t, knots_t, rng.uniform(15.0, 30.0, len(knots_t)))
    position = np.concatenate([[0.0], np.cumsum(speed[:-1]) / fs])
    scale = speed / MEAN_SPEED

    data = np.empty((n, len(CHANNELS)), np.float32)
    for c, group in enumerate(CHANNEL_GROUPS):
        g = GROUPS[group]
        f, amp, phi = rng.uniform(*g.f), rng.uniform(*g.amp), rng.uniform(0, 2 * np.pi)
        phase = phi + 2 * np.pi * f * np.concatenate([[0.0], np.cumsum(scale[:-1]) / fs])
        clean = amp * scale * np.sin(phase)
        data[:, c] = clean + _noise_levels(rng, n, fs, g.sigma, g.d_sigma) * rng.standard_normal(n)

    defects = []
    for at in _defect_times(rng, duration_s, defect_every_s):
        c = int(rng.integers(len(CHANNELS)))
        spike = bool(rng.random() < 0.5)
        duration = 0.01 if spike else float(rng.uniform(0.05, 0.2))
        size = rng.uniform(*(spike_offset if spike else deviation_offset))
        offset = float(size * rng.choice([-1.0, 1.0]))
        i0 = int(round(at * fs))
        i1 = max(i0 + 1, int(round((at + duration) * fs)))
        data[i0:i1, c] += offset
        defects.append({"time_s": at, "duration_s": duration, "center_s": at + duration / 2,
                        "position_m": float(np.interp(at + duration / 2, t, position)),
                        "channel": CHANNELS[c], "group": CHANNEL_GROUPS[c],
                        "kind": "spike" if spike else "deviation", "offset": offset})
    return Run(fs=fs, data=data, time=t, speed=speed, position=position, defects=defects)


def _noise_levels(rng: np.random.Generator, n: int, fs: float, sigma: tuple[float, float],
                  d_sigma: tuple[float, float]) -> NDArray[np.float64]:
    """Per-sample noise std: a new level σ + b·Δσ every U[0.4, 1.6] s."""
    levels = np.empty(n)
    i = 0
    while i < n:
        length = max(1, int(rng.uniform(0.4, 1.6) * fs))
        levels[i:i + length] = rng.uniform(*sigma) + (rng.random() < 0.5) * rng.uniform(*d_sigma)
        i += length
    return levels


def _defect_times(rng: np.random.Generator, duration_s: float, every_s: float) -> list[float]:
    """Poisson arrivals with mean spacing ``every_s``, at least 2 s apart and 2 s from the ends."""
    times: list[float] = []
    at = 2.0
    while True:
        at += max(2.0, float(rng.exponential(every_s)))
        if at > duration_s - 2.0:
            return times
        times.append(round(at, 4))
