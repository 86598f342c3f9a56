"""One track, many passes: the repeated-pass mode of ``generate-run``.

A **track** is a length of line with defects at fixed positions: each has a kind (spike or local
deviation), a size and sign, a length along the rail (a local deviation: 1.1–4.5 m, the
benchmark's 0.05–0.2 s at 22.5 m/s; a spike: one sample at 100 Hz at any speed), and the
channel group and side of the vehicle that feels it (at stage 6 and later drawn by the kind's
odds, as the benchmark's anomalous channel). With ``loud_stretches`` its rough sections (noise
×2–4 over 200–1500 m) belong to the track too, so they are the same on every pass.

A **pass** is one run over the track (the signals of :mod:`railwatch.synthetic.runs`: its own
speed profile, noise, HF bursts and impulses), entering at its own start offset, in either
direction; a defect is felt when the vehicle is over it, for as long as the vehicle takes to
cross it, on the side of the vehicle that is over its rail (the sides swap when the vehicle runs
the other way, as on a vehicle turned at the line's ends; with ``push_pull`` they stay, as on a
vehicle that runs back without turning). The recorded ``position`` column is the odometry's,
not the truth: the true position where the pass starts plus an offset error, a scale error
(drift: the wheel's radius is not known exactly) and a random walk, as a vehicle's odometry or
GPS drifts by metres.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.atomic import atomic_csv, atomic_path
from railwatch.errors import RailwatchError
from railwatch.synthetic.runs import (
    CHANNEL_GROUPS,
    CHANNELS,
    MEAN_SPEED,
    RUN_STAGES,
    STRETCH_GAIN,
    STRETCH_M,
    STRETCH_SHARE,
    Run,
    render,
    speed_profile,
)
from railwatch.synthetic.stages import P_LOCAL, P_SPIKE

#: Columns of a track's true-defects table (one row per defect, positions along the track).
TRACK_FIELDS = ("defect", "position_m", "length_m", "kind", "offset", "group", "side")
#: Columns of a pass's true-defects table: where and when this pass crossed each defect.
PASS_FIELDS = ("defect", "time_s", "duration_s", "center_s", "position_m", "recorded_m",
               "channel", "group", "kind", "offset")

#: Defects are at least this far apart and from the track's ends (m).
MIN_GAP_M = 25.0


@dataclass(frozen=True)
class TrackDefect:
    defect: int  # index on the track
    position_m: float  # where it starts along the track
    length_m: float  # along the rail (0: a spike, one sample)
    kind: str  # "spike" | "deviation"
    offset: float  # signed size
    group: str  # axle | bogie | body
    side: int  # 1 or 2: which of the group's two channels, running forwards


@dataclass(frozen=True)
class Odometry:
    """How the recorded position errs: an offset (m, std), a relative scale error (std) and a
    random walk (m of std per √km travelled). ``relative``: the position is the distance counted
    from the pass's own start (an odometer alone), not the track's position."""

    offset_m: float = 1.0
    drift: float = 0.0005
    walk_m: float = 0.3
    relative: bool = False


@dataclass
class Track:
    length_m: float
    defects: list[TrackDefect]
    seed: int
    stage: int = 5
    #: Rough sections: (start m, end m, noise gain); empty without loud stretches.
    stretches: list[tuple[float, float, float]] = field(default_factory=list)

    def gain_at(self, x: NDArray[np.float64]) -> NDArray[np.float64] | float:
        """Noise gain of the track at true positions ``x`` (1 off the rough sections)."""
        if not self.stretches:
            return 1.0
        gain = np.ones(len(x))
        for start, end, g in self.stretches:
            gain[(x >= start) & (x < end)] = g
        return gain

    def write(self, path: str | os.PathLike[str]) -> Path:
        """The true defects, by position, as CSV (:data:`TRACK_FIELDS`)."""
        return atomic_csv(path, TRACK_FIELDS, [asdict(d) for d in self.defects])


def make_track(length_m: float = 10_000.0, n_defects: int = 40, seed: int = 0, stage: int = 5,
               loud_stretches: bool = False,
               spike_offset: tuple[float, float] = (3.0, 4.0),
               deviation_offset: tuple[float, float] = (1.5, 2.0)) -> Track:
    """A track with ``n_defects`` at random positions, at least :data:`MIN_GAP_M` apart."""
    if stage not in RUN_STAGES:
        raise RailwatchError(f"a track carries stage 5, 6, 7 or 8, got {stage}")
    room = length_m - 2 * MIN_GAP_M - (n_defects - 1) * MIN_GAP_M
    if length_m <= 0 or n_defects < 0 or room < 0:
        raise RailwatchError(f"{n_defects} defects {MIN_GAP_M:g} m apart do not fit on "
                             f"{length_m:g} m of track")
    rng = np.random.default_rng([seed, 100])
    # Sorted uniform gaps, then the minimum gap added between neighbours: uniform, spaced.
    free = np.sort(rng.uniform(0.0, room, n_defects))
    positions = MIN_GAP_M + free + MIN_GAP_M * np.arange(n_defects)
    spikes = rng.permutation(n_defects) < (n_defects + 1) // 2  # half spikes, in random places
    defects = []
    for i, (at, spike) in enumerate(zip(positions, spikes, strict=True)):
        odds = P_SPIKE if spike else P_LOCAL
        c = int(rng.choice(len(CHANNELS), p=odds)) if stage >= 6 else \
            int(rng.integers(len(CHANNELS)))
        size = rng.uniform(*(spike_offset if spike else deviation_offset))
        length = 0.0 if spike else float(rng.uniform(0.05, 0.2) * MEAN_SPEED)
        defects.append(TrackDefect(
            defect=i, position_m=round(float(at), 3), length_m=round(length, 3),
            kind="spike" if spike else "deviation",
            offset=float(size * rng.choice([-1.0, 1.0])), group=CHANNEL_GROUPS[c],
            side=c % 2 + 1))
    stretches = []
    if loud_stretches:
        srng = np.random.default_rng([seed, 101])
        start = 0.0
        while start < length_m:
            end = start + srng.uniform(*STRETCH_M)
            if srng.random() < STRETCH_SHARE:
                stretches.append((start, end, float(srng.uniform(*STRETCH_GAIN))))
            start = end
    return Track(length_m=length_m, defects=defects, seed=seed, stage=stage,
                 stretches=stretches)


@dataclass
class Pass:
    run: Run  # position: the recorded (odometry) position
    direction: int  # +1: along increasing track position
    true_position: NDArray[np.float64]  # (n,) m
    crossings: list[dict[str, Any]]  # PASS_FIELDS

    def write_truth(self, path: str | os.PathLike[str]) -> Path:
        return atomic_csv(path, PASS_FIELDS, self.crossings)


def synthesize_pass(track: Track, seed: int, fs: float = 2000.0, direction: int = 1,
                    start_m: float | None = None, odometry: Odometry | None = None,
                    push_pull: bool = False) -> Pass:
    """One pass over ``track`` (module docstring): it enters at ``start_m`` from its end
    (default U[0, 200] m) and runs to within 200 m of the other end; backwards (``direction``
    −1) a defect is felt on the other side of the vehicle unless ``push_pull``."""
    if direction not in (1, -1):
        raise RailwatchError(f"direction is 1 or -1, got {direction}")
    odometry = odometry or Odometry()
    rng = np.random.default_rng([seed, 200])
    burst_rng, impulse_rng, odo_rng = (np.random.default_rng([seed, k]) for k in (207, 208, 209))
    enter = float(rng.uniform(0.0, 200.0)) if start_m is None else float(start_m)
    leave = float(rng.uniform(0.0, 200.0))
    distance = track.length_m - enter - leave
    if distance <= 0:
        raise RailwatchError(f"a pass entering at {enter:g} m does not cross the track")
    speed_all, _ = speed_profile(rng, distance / 15.0 + 60.0, fs)
    travel_m = np.concatenate([[0.0], np.cumsum(speed_all[:-1]) / fs])
    n = int(np.searchsorted(travel_m, distance)) + 1
    speed, travel_m = speed_all[:n], travel_m[:n]
    t = np.arange(n) / fs
    true = enter + travel_m if direction == 1 else track.length_m - enter - travel_m
    scale = speed / MEAN_SPEED
    data = render(rng, burst_rng, impulse_rng, t, travel_m, scale, track.gain_at(true),
                  track.stage, fs)
    crossings: list[dict[str, Any]] = []
    for d in track.defects:
        if not min(true[0], true[-1]) <= d.position_m <= max(true[0], true[-1]):
            continue
        # The vehicle is over [position, position + length] of the track.
        ends = sorted(abs(x - true[0]) for x in (d.position_m, d.position_m + d.length_m))
        i0, i1 = (int(np.searchsorted(travel_m, e)) for e in ends)
        if d.kind == "spike":
            i1 = i0 + max(1, int(round(0.01 * fs)))
        i1 = min(max(i1, i0 + 1), n)
        side = d.side if direction == 1 or push_pull else 3 - d.side
        c = CHANNELS.index(f"{d.group}_{side}")
        data[i0:i1, c] += d.offset
        crossings.append({"defect": d.defect, "time_s": round(float(t[i0]), 6),
                          "duration_s": (i1 - i0) / fs,
                          "center_s": round(float(t[i0] + (i1 - i0) / (2 * fs)), 6),
                          "position_m": d.position_m, "recorded_m": 0.0,
                          "channel": CHANNELS[c], "group": d.group, "kind": d.kind,
                          "offset": d.offset})
    crossings.sort(key=lambda row: row["time_s"])
    recorded = recorded_position(odo_rng, true[0], travel_m, direction, odometry)
    for row in crossings:
        row["recorded_m"] = float(np.interp(row["center_s"], t, recorded))
    run = Run(fs=fs, data=data, time=t, speed=speed, position=recorded,
              defects=crossings)
    return Pass(run=run, direction=direction, true_position=true, crossings=crossings)


def write_track(out: str | os.PathLike[str], passes: int, length_m: float = 10_000.0,
                n_defects: int = 40, seed: int = 0, stage: int = 5, fs: float = 2000.0,
                loud_stretches: bool = False, odometry: Odometry | None = None,
                suffix: str = ".parquet", push_pull: bool = False,
                progress: Any = None) -> tuple[Track, list[Path]]:
    """A track and ``passes`` passes over it, written into the folder ``out``: ``track.defects.csv``
    (true defects by position), ``layout.toml`` (every pass's columns), and per pass
    ``passNN<suffix>`` (the recording) and ``passNN.defects.csv`` (when and where it crossed each
    defect). Pass ``i`` runs forwards when ``i`` is even, backwards when odd (a vehicle turned
    at the ends, or with ``push_pull`` one that runs back without turning); each has its own
    seed, start offset and odometry error. ``track.defects.csv`` is written last, so a folder
    that has it holds every pass. Returns the track and the recordings' paths."""
    from railwatch.recordings.layout import layout_toml
    from railwatch.recordings.readers import FORMATS, write_recording

    if suffix not in FORMATS:
        raise RailwatchError(f"--format {suffix.lstrip('.')}: use csv, parquet, h5 or mat")
    if passes < 1:
        raise RailwatchError(f"--passes must be at least 1, got {passes}")
    if fs < 100:
        raise RailwatchError(f"--fs must be at least 100 Hz (a spike lasts 0.01 s), got {fs:g}")
    track = make_track(length_m, n_defects, seed=seed, stage=stage, loud_stretches=loud_stretches)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / "layout.toml") as tmp:
        tmp.write_text(layout_toml(Run.layout(fs)))
    paths = []
    for i in range(passes):
        p = synthesize_pass(track, seed=seed * 1000 + i + 1, fs=fs,
                            direction=1 if i % 2 == 0 else -1, odometry=odometry,
                            push_pull=push_pull)
        name = f"pass{i + 1:02d}"
        p.write_truth(out / f"{name}.defects.csv")
        paths.append(write_recording(out / f"{name}{suffix}", p.run.columns()))
        if progress is not None:
            progress(1)
    track.write(out / "track.defects.csv")  # last: a folder with it holds every pass
    return track, paths


def recorded_position(rng: np.random.Generator, start: float, travel_m: NDArray[np.float64],
                      direction: int, odo: Odometry) -> NDArray[np.float64]:
    """The recorded position: start + offset error + direction · (1 + scale error) · travel +
    a random walk of ``walk_m`` per √km (relative odometry: the offset error + (1 + scale
    error) · travel + the walk)."""
    offset = float(rng.normal(0.0, odo.offset_m))
    scale = 1.0 + float(rng.normal(0.0, odo.drift))
    steps = np.diff(travel_m, prepend=0.0)
    walk = np.cumsum(rng.standard_normal(len(travel_m)) * odo.walk_m * np.sqrt(steps / 1000.0))
    if odo.relative:
        return offset + scale * travel_m + walk
    return start + offset + direction * scale * travel_m + walk
