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

The later stages' nuisance comes in continuous time with ``stage`` (each draws from its own seed
stream, so a stage-8 run is its stage-5 run plus the added components, same signal, noise and
defects):

- ``stage >= 6``: a defect's channel is drawn from the kind-specific odds (spikes favour the axle,
  local deviations the body);
- ``stage >= 7``: **HF bursts tied to track position**: per channel, rough spots along the track
  (Poisson, one per 45 m on average, the benchmark's one per 2-s window at 22.5 m/s), each
  0.05–0.2 s long at 22.5 m/s (1.1–4.5 m), a sine of the group's α and f_HF ranges whose
  frequency and amplitude scale with speed as the base sinusoid's do;
- ``stage >= 8``: **wheel-periodic impulses**: per channel, one truncated Gaussian impulse every
  L = T · 22.5 m of travel (T, ω and β from the group's Stage-8 ranges at 22.5 m/s), so the
  period in time is L / v; width ω · 22.5 / v, height β · v / 22.5.

A :class:`Variation` makes a run differently from the runs the detectors were developed on (the
generalisation tests of ``docs/nuisance-glr.md``): the speed's knots closer or its range wider,
a noise level that ramps between its knots instead of stepping, a vibration with harmonics (not
a sinusoid), local deviations of another shape. ``Variation()`` is the runs as they were.

``loud_stretches`` adds **long stretches of rough track**: the track is cut into sections of
200–1500 m (9–67 s at 22.5 m/s); each is rough with probability 0.4 and multiplies the white
noise of every channel by U[2, 4] over its whole length. A detector that learned one noise level,
or an event threshold fixed at training time, sees tens of seconds of louder signal.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.errors import RailwatchError
from railwatch.recordings.layout import Layout
from railwatch.synthetic.stages import GROUPS, P_LOCAL, P_SPIKE, GroupRanges

CHANNELS = ("axle_1", "axle_2", "bogie_1", "bogie_2", "body_1", "body_2")
CHANNEL_GROUPS = ("axle", "axle", "bogie", "bogie", "body", "body")
MEAN_SPEED = 22.5  # m/s: speed at which f and A are the drawn values
RUN_STAGES = (5, 6, 7, 8)  # the benchmark stages a run carries into continuous time

#: HF bursts: mean spacing along the track (m) and length range at MEAN_SPEED (s).
BURST_SPACING_M = 2.0 * MEAN_SPEED
BURST_S = (0.05, 0.2)
#: Loud stretches: section lengths (m), share of rough sections, noise gain on a rough one.
STRETCH_M = (200.0, 1500.0)
STRETCH_SHARE = 0.4
STRETCH_GAIN = (2.0, 4.0)


#: Columns of the true-defects table (one row per defect).
DEFECT_FIELDS = ("time_s", "duration_s", "center_s", "position_m", "channel", "group", "kind",
                 "offset")


#: Shapes a local deviation may take (:class:`Variation`): over its span u = 0..1, the offset
#: times 1 (a box), 1 − |2u − 1| (a triangle) or sin(π u) (half a sine).
SHAPES = ("box", "triangle", "half-sine")


@dataclass(frozen=True)
class Variation:
    """How a run is made differently (module docstring); the defaults are the runs as made."""

    speed_knot_s: float = 30.0  # the speed is piecewise linear between knots this far apart
    speed_range: tuple[float, float] = (15.0, 30.0)  # m/s, drawn at every knot
    noise_ramps: bool = False  # the noise level ramps linearly from knot to knot (not steps)
    harmonics: tuple[float, ...] = ()  # amplitudes of the 2nd, 3rd, ... harmonics, per unit
    deviation_shape: str = "box"  # a local deviation's shape over its span (SHAPES)

    def __post_init__(self) -> None:
        low, high = self.speed_range
        if not (self.speed_knot_s > 0 and 0 < low <= high):
            raise RailwatchError(f"a variation needs speed_knot_s > 0 and 0 < low <= high m/s, "
                                 f"got {self.speed_knot_s} and {self.speed_range}")
        if self.deviation_shape not in SHAPES:
            raise RailwatchError(f"deviation_shape must be one of {', '.join(SHAPES)}, got "
                                 f"{self.deviation_shape!r}")


def deviation(shape: str, n: int) -> NDArray[np.float64]:
    """The ``n`` samples of a unit local deviation of ``shape`` (:data:`SHAPES`), at the
    samples' centres."""
    u = (np.arange(n) + 0.5) / n
    if shape == "triangle":
        return 1.0 - np.abs(2 * u - 1)
    if shape == "half-sine":
        return np.sin(np.pi * u)
    return np.ones(n)


@dataclass
class Run:
    fs: float
    data: NDArray[np.float32]  # (n, 6)
    time: NDArray[np.float64]  # (n,) s
    speed: NDArray[np.float64]  # (n,) m/s
    position: NDArray[np.float64]  # (n,) m
    defects: list[dict[str, Any]] = field(default_factory=list)
    #: With ``synthesize_run(components=True)``: the signal without white noise and defects
    #: (sinusoids, bursts, impulses) and the white noise's std at every sample (n, 6), as the
    #: window generator's ``components`` hand them to the oracle.
    nuisance: NDArray[np.float32] | None = None
    noise_std: NDArray[np.float32] | None = None

    def columns(self) -> dict[str, NDArray[Any]]:
        """The run as named columns: time, speed, position, then the six channels."""
        cols: dict[str, NDArray[Any]] = {"time": self.time, "speed": self.speed,
                                         "position": self.position}
        cols.update({c: self.data[:, i] for i, c in enumerate(CHANNELS)})
        return cols

    @staticmethod
    def layout(fs: float = 2000.0, with_position: bool = True) -> Layout:
        """The layout of :meth:`columns` written to a file: the benchmark's scale (a defect
        lasts 0.01-0.2 s, twenty times a real one)."""
        return Layout(fs=fs, channels=CHANNELS, groups=CHANNEL_GROUPS, time="time",
                      speed="speed", position="position" if with_position else None,
                      scale="benchmark")


def synthesize_run(
    duration_s: float = 600.0,
    seed: int = 0,
    fs: float = 2000.0,
    defect_every_s: float = 10.0,
    spike_offset: tuple[float, float] = (3.0, 4.0),
    deviation_offset: tuple[float, float] = (1.5, 2.0),
    stage: int = 5,
    loud_stretches: bool = False,
    components: bool = False,
    variation: Variation | None = None,
) -> Run:
    """A continuous six-channel run with defects at known times; see the module docstring.
    ``components=True`` keeps the run's nuisance signal and noise std (:class:`Run`);
    ``variation`` makes it differently (:class:`Variation`)."""
    variation = variation or Variation()
    if fs < 100.0:
        raise RailwatchError(f"a run needs fs >= 100 Hz (a spike lasts 0.01 s), got {fs:g}")
    if stage not in RUN_STAGES:
        raise RailwatchError(f"a run carries stage 5, 6, 7 or 8 into continuous time, got {stage}")
    rng = np.random.default_rng(seed)
    # Added components draw from their own streams: the stage-5 run stays as it was.
    odds_rng, burst_rng, impulse_rng, stretch_rng = (
        np.random.default_rng([seed, k]) for k in (6, 7, 8, 9))
    speed, t = speed_profile(rng, duration_s, fs, variation.speed_knot_s, variation.speed_range)
    position = np.concatenate([[0.0], np.cumsum(speed[:-1]) / fs])
    scale = speed / MEAN_SPEED

    gain = _stretch_gain(stretch_rng, position) if loud_stretches else 1.0
    parts: dict[str, NDArray[np.float32]] | None = {} if components else None
    data = render(rng, burst_rng, impulse_rng, t, position, scale, gain, stage, fs, parts,
                  variation)

    defects = []
    for at in _defect_times(rng, duration_s, defect_every_s):
        c = int(rng.integers(len(CHANNELS)))
        spike = bool(rng.random() < 0.5)
        if stage >= 6:  # the same defect as at stage 5, on a channel drawn by its kind's odds
            c = int(odds_rng.choice(len(CHANNELS), p=P_SPIKE if spike else P_LOCAL))
        duration = 0.01 if spike else float(rng.uniform(0.05, 0.2))
        size = rng.uniform(*(spike_offset if spike else deviation_offset))
        offset = float(size * rng.choice([-1.0, 1.0]))
        i0 = int(round(at * fs))
        i1 = max(i0 + 1, int(round((at + duration) * fs)))
        shape = "box" if spike else variation.deviation_shape
        data[i0:i1, c] += (offset * deviation(shape, i1 - i0)).astype(data.dtype)
        defects.append({"time_s": at, "duration_s": duration, "center_s": at + duration / 2,
                        "position_m": float(np.interp(at + duration / 2, t, position)),
                        "channel": CHANNELS[c], "group": CHANNEL_GROUPS[c],
                        "kind": "spike" if spike else "deviation", "offset": offset})
    return Run(fs=fs, data=data, time=t, speed=speed, position=position, defects=defects,
               **(parts or {}))


def speed_profile(rng: np.random.Generator, duration_s: float, fs: float, knot_s: float = 30.0,
                  speed_range: tuple[float, float] = (15.0, 30.0)
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The train's speed (m/s) at every sample of ``duration_s`` and the sample times: piecewise
    linear between knots every ``knot_s`` (30 s), drawn from U[``speed_range``] (15-30 m/s)."""
    n = int(round(duration_s * fs))
    t = np.arange(n) / fs
    knots_t = np.arange(0.0, duration_s + knot_s, knot_s)
    return np.interp(t, knots_t, rng.uniform(*speed_range, len(knots_t))), t


def render(rng: np.random.Generator, burst_rng: np.random.Generator,
           impulse_rng: np.random.Generator, t: NDArray[np.float64],
           position: NDArray[np.float64], scale: NDArray[np.float64],
           gain: NDArray[np.float64] | float, stage: int, fs: float,
           parts: dict[str, NDArray[np.float32]] | None = None,
           variation: Variation | None = None) -> NDArray[np.float32]:
    """The six channels of a run without defects (n, 6): sinusoids scaled by speed, white noise
    of changing level times the track's ``gain``, and from ``stage`` 7 and 8 the bursts and
    impulses, placed by ``position``, the distance travelled (increasing). ``parts``, if
    given, receives ``nuisance`` (all but the white noise) and ``noise_std`` (its std), (n, 6).
    ``variation``: the noise's ramps and the vibration's harmonics (:class:`Variation`)."""
    variation = variation or Variation()
    # the harmonics' phases draw from a stream of their own: the other draws stay as they were
    harmonic_rng = None
    if variation.harmonics:
        seeds = rng.bit_generator.seed_seq
        assert isinstance(seeds, np.random.SeedSequence)
        harmonic_rng = np.random.default_rng(seeds.spawn(1)[0])
    n = len(t)
    travel = _travel(scale, fs)
    data = np.empty((n, len(CHANNELS)), np.float32)
    keep = parts is not None
    nuisance = np.zeros((n, len(CHANNELS)), np.float32) if keep else None
    std = np.zeros((n, len(CHANNELS)), np.float32) if keep else None
    for c, group in enumerate(CHANNEL_GROUPS):
        g = GROUPS[group]
        f, amp, phi = rng.uniform(*g.f), rng.uniform(*g.amp), rng.uniform(0, 2 * np.pi)
        phase = phi + 2 * np.pi * f * travel
        clean = amp * scale * np.sin(phase)
        for k, share in enumerate(variation.harmonics, start=2):
            assert harmonic_rng is not None
            clean += share * amp * scale * np.sin(k * phase + harmonic_rng.uniform(0, 2 * np.pi))
        level = _noise_levels(rng, n, fs, g.sigma, g.d_sigma, variation.noise_ramps)
        data[:, c] = clean + gain * (level * rng.standard_normal(n))
        if nuisance is not None and std is not None:
            nuisance[:, c], std[:, c] = clean, gain * level
    for c, group in enumerate(CHANNEL_GROUPS):
        added = []
        if stage >= 7:
            added.append(_bursts(burst_rng, GROUPS[group], position, scale, travel))
        if stage >= 8:
            added.append(_impulses(impulse_rng, GROUPS[group], t, position, scale, fs))
        for a in added:
            data[:, c] += a
            if nuisance is not None:
                nuisance[:, c] += a
    if parts is not None and nuisance is not None and std is not None:
        parts.update(nuisance=nuisance, noise_std=std)
    return data


def _travel(scale: NDArray[np.float64], fs: float) -> NDArray[np.float64]:
    """Seconds of travel at MEAN_SPEED covered by each sample: ∫ v/v̄ dt, 0 at the first sample."""
    return np.concatenate([[0.0], np.cumsum(scale[:-1]) / fs])


def _stretch_gain(rng: np.random.Generator, position: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per-sample noise gain of the track under the train: 1, or U[2, 4] over a rough section."""
    gain = np.ones(len(position))
    start = 0.0
    while start <= position[-1]:
        end = start + rng.uniform(*STRETCH_M)
        if rng.random() < STRETCH_SHARE:
            i0, i1 = np.searchsorted(position, [start, end])
            gain[i0:i1] = rng.uniform(*STRETCH_GAIN)
        start = end
    return gain


def _bursts(rng: np.random.Generator, g: GroupRanges, position: NDArray[np.float64],
            scale: NDArray[np.float64], travel: NDArray[np.float64]) -> NDArray[np.float64]:
    """One channel's HF bursts at rough spots of the track (module docstring); ``travel`` is
    :func:`_travel` of the run."""
    out = np.zeros(len(position))
    at = float(rng.exponential(BURST_SPACING_M))
    while at < position[-1]:
        length = rng.uniform(*BURST_S) * MEAN_SPEED
        alpha, f_hf, psi = rng.uniform(*g.alpha_hf), rng.uniform(*g.f_hf), rng.uniform(0, 2 * np.pi)
        i0, i1 = np.searchsorted(position, [at, at + length])
        if i1 > i0:  # the frequency follows speed: a spatial wavelength of the track
            out[i0:i1] = alpha * scale[i0:i1] * np.sin(2 * np.pi * f_hf * travel[i0:i1] + psi)
        at += length + float(rng.exponential(BURST_SPACING_M))
    return out


def _impulses(rng: np.random.Generator, g: GroupRanges, t: NDArray[np.float64],
              position: NDArray[np.float64], scale: NDArray[np.float64],
              fs: float) -> NDArray[np.float64]:
    """One channel's wheel-periodic impulses: one every T · 22.5 m of travel (module docstring)."""
    out = np.zeros(len(t))
    omega, period, beta = rng.uniform(*g.omega), rng.uniform(*g.imp_period), rng.uniform(*g.beta)
    spacing = period * MEAN_SPEED
    first = rng.uniform(0.0, spacing)
    for x in np.arange(first, position[-1], spacing):
        i0 = int(np.searchsorted(position, x))
        if i0 >= len(t):
            break
        width = omega / scale[i0]  # seconds: the wheel passes faster at speed
        i1 = min(len(t), i0 + int(np.ceil(3 * width * fs)) + 1)
        tau = t[i0:i1] - t[i0]
        out[i0:i1] += beta * scale[i0] * np.exp(-np.square(tau / width)) * (tau <= 3 * width)
    return out


def _noise_levels(rng: np.random.Generator, n: int, fs: float, sigma: tuple[float, float],
                  d_sigma: tuple[float, float], ramps: bool = False) -> NDArray[np.float64]:
    """Per-sample noise std: a new level σ + b·Δσ every U[0.4, 1.6] s; with ``ramps``, the
    level goes linearly from each one to the next instead of stepping."""
    levels = np.empty(n)
    starts, values = [], []
    i = 0
    while i < n:
        length = max(1, int(rng.uniform(0.4, 1.6) * fs))
        value = rng.uniform(*sigma) + (rng.random() < 0.5) * rng.uniform(*d_sigma)
        levels[i:i + length] = value
        starts.append(i)
        values.append(value)
        i += length
    if ramps and len(starts) > 1:
        return np.interp(np.arange(n), starts, values)
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
