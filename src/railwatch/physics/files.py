"""A physics track and its passes written as recordings: what ``railwatch simulate`` makes.

The folder holds what ``generate-run --passes`` writes, so every workflow reads it alike, and
what only a physics world can give:

=========================== ================================================================
``layout.toml``             the recordings' columns: time, speed, position, six channels
``passNN.<format>``         pass NN as a logger records it (position: the odometry's)
``passNN.defects.csv``      when and where pass NN's sensors crossed each defect, at what speed,
                            and which axle-box channel ran on its rail
``passNN.features.csv``     the same for the features (turnouts, transitions, level crossings)
``twins/passNN.<format>``   pass NN's clean twin: the same pass without the defects and the
                            sensor noise (same columns)
``track.features.csv``      the features along the track
``physics.json``            every setting (vehicle, track, spectra, sensors, each pass's
                            direction and speed range), the sensor noise per channel, and per
                            pass where a wheel left the rail and its highest wheel load
``track.defects.csv``       the defects along the track: written last, so a folder that has it
                            holds every pass
=========================== ================================================================
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from railwatch.atomic import atomic_csv, atomic_path
from railwatch.errors import RailwatchError
from railwatch.physics.dynamics import coupled
from railwatch.physics.features import ITEM_FIELDS
from railwatch.physics.passes import MIN_SIM_RATE, PassPlan, PhysicsPass, simulate_pass
from railwatch.physics.vehicle import CHANNELS, GROUPS
from railwatch.physics.world import PhysicsTrack, World, build_track
from railwatch.recordings.layout import Layout, layout_toml
from railwatch.recordings.readers import FORMATS, write_recording
from railwatch.synthetic.track import Odometry, recorded_position

#: Columns of a pass's crossings tables (passNN.defects.csv, passNN.features.csv).
CROSSING_FIELDS = ("defect", "kind", "time_s", "duration_s", "center_s", "position_m",
                   "recorded_m", "length_m", "depth_mm", "rail", "channel", "speed_ms")


def layout(fs: float) -> Layout:
    """The layout of a physics pass written at ``fs`` Hz."""
    return Layout(fs=fs, channels=CHANNELS, groups=GROUPS, time="time", speed="speed",
                  position="position")


def write_world(out: str | os.PathLike[str], passes: int, world: World, seed: int = 0,
                plan: PassPlan | None = None, odometry: Odometry | None = None,
                suffix: str = ".parquet",
                progress: Callable[[int], Any] | None = None) -> tuple[PhysicsTrack, list[Path]]:
    """Build ``world``'s track from ``seed`` and simulate ``passes`` passes over it into the
    folder ``out`` (module docstring). Pass ``i`` (from 0) runs along increasing position when
    ``i`` is even and back when odd, each with its own seed (``seed · 1000 + i + 1``), speed
    profile, start and odometry error; ``plan`` gives the rest (its direction is ignored).
    Returns the track and the recordings' paths."""
    if suffix not in FORMATS:
        raise RailwatchError(f"--format {suffix.lstrip('.')}: use csv, parquet, h5 or mat")
    if passes < 1:
        raise RailwatchError(f"--passes must be at least 1, got {passes}")
    plan = plan or PassPlan()
    world.check()
    plan.check()
    odometry = odometry or Odometry()
    out = Path(out)
    (out / "twins").mkdir(parents=True, exist_ok=True)
    track = build_track(world, seed)
    q = max(2, int(np.ceil(MIN_SIM_RATE / plan.fs)))
    coupling = coupled(world.vehicle, world.track, q * plan.fs / 2)
    with atomic_path(out / "layout.toml") as tmp:
        tmp.write_text(layout_toml(layout(plan.fs)))
    paths, summaries = [], []
    for i in range(passes):
        pass_seed = seed * 1000 + i + 1
        direction = 1 if i % 2 == 0 else -1
        p = simulate_pass(track, PassPlan(direction, plan.push_pull, plan.speed_ms, plan.fs),
                          pass_seed, coupling)
        name = f"pass{i + 1:02d}"
        _record_positions(p, direction, odometry, pass_seed)
        for rows, kind in ((p.crossings, "defects"), (p.features, "features")):
            atomic_csv(out / f"{name}.{kind}.csv", CROSSING_FIELDS, rows)
        write_recording(out / "twins" / f"{name}{suffix}", p.twin)
        paths.append(write_recording(out / f"{name}{suffix}", p.columns))
        summaries.append({"pass": name, "seed": pass_seed, "direction": direction,
                          "minutes": round(float(p.columns["time"][-1]) / 60, 3),
                          "speed_ms": [round(float(p.columns["speed"].min()), 2),
                                       round(float(p.columns["speed"].max()), 2)],
                          "wheel_left_rail_m": [round(x, 2) for x in p.flights_m],
                          "peak_wheel_load": round(p.peak_load, 3)})
        if progress is not None:
            progress(1)
    atomic_csv(out / "track.features.csv", ITEM_FIELDS, [it.row() for it in track.features])
    info = {"seed": seed, "passes": summaries, "fs": plan.fs, "speed_ms": list(plan.speed_ms),
            "push_pull": plan.push_pull, "odometry": asdict(odometry),
            "sensor_noise_ms2": dict(zip(CHANNELS, world.sensors.noise().tolist(), strict=True)),
            "world": world.to_dict(), "docs": "docs/physics.md"}
    with atomic_path(out / "physics.json") as tmp:
        tmp.write_text(json.dumps(info, indent=1, default=_plain) + "\n")
    atomic_csv(out / "track.defects.csv", ITEM_FIELDS, [it.row() for it in track.defects])
    return track, paths


def _record_positions(p: PhysicsPass, direction: int, odometry: Odometry, seed: int) -> None:
    """Replace the pass's (and its twin's) true positions by the odometry's, and give each
    crossing the recorded position of its centre."""
    true = p.columns["position"]
    travel = np.abs(true - true[0])
    recorded = recorded_position(np.random.default_rng([seed, 209]), float(true[0]), travel,
                                 direction, odometry)
    p.columns["position"] = recorded
    p.twin["position"] = recorded
    time = p.columns["time"]
    for row in [*p.crossings, *p.features]:
        row["recorded_m"] = round(float(np.interp(row["center_s"], time, recorded)), 4)


def _plain(value: Any) -> Any:
    """JSON for numpy scalars and tuples inside the settings."""
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")
