"""A physics track and its passes written as recordings: what ``railwatch simulate`` makes.

The folder holds what ``generate-run --passes`` writes, so every workflow reads it alike, and
what only a physics world can give:

=========================== ================================================================
``layout.toml``             the recordings' columns: time, speed, position, lat and lon (the
                            GNSS fixes, :mod:`railwatch.physics.gnss`), six channels
``passNN.<format>``         pass NN as a logger records it (position: the odometry's)
``passNN.defects.csv``      when and where pass NN's sensors crossed each defect, at what speed,
                            and which axle-box channel ran on its rail
``passNN.features.csv``     the same for the features (turnouts, transitions, level crossings)
``twins/passNN.<format>``   pass NN's clean twin: the same pass without its defects, its
                            sensor noise and its odometry's error (same columns; the position
                            is the true one)
``track.features.csv``      the features along the track
``track.assets.csv``        the same as an asset register (``track-map --assets``): id, kind
                            (switch, crossing, bridge transition, level crossing), position_m,
                            length_m
``physics.json``            every setting (vehicle, track, spectra, sensors, each pass's
                            direction and speed range), the sensor noise per channel, and per
                            pass where a wheel left the rail and its highest wheel load
``track.defects.csv``       the defects along the track: written last, so a folder that has it
                            holds every pass
=========================== ================================================================
"""

from __future__ import annotations

import json
import math
import os
import shutil
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.atomic import atomic_csv, atomic_path
from railwatch.errors import RailwatchError
from railwatch.physics import gnss
from railwatch.physics.dynamics import coupled
from railwatch.physics.features import ITEM_FIELDS, Inventory, Item
from railwatch.physics.passes import PassPlan, PhysicsPass, oversampling, simulate_pass
from railwatch.physics.vehicle import CHANNELS, GROUPS
from railwatch.physics.world import MARGIN_M, PhysicsTrack, World, build_track, grown
from railwatch.recordings.layout import Layout, layout_toml, load_layout
from railwatch.recordings.readers import FORMATS, Recording, write_recording
from railwatch.synthetic.track import Odometry, recorded_position


@dataclass(frozen=True)
class Positioning:
    """Where a recording says the vehicle was: each pass's own odometry errors (its start's
    offset, its scale error, a random walk), and the errors all passes of one vehicle share (a
    common offset of the reference its odometer is set by, m std; a common scale error of its
    wheel's worn radius, std), drawn once per folder."""

    odometry: Odometry = field(default_factory=Odometry)
    common_offset_m: float = 0.0
    common_drift: float = 0.0


#: An odometer alone: a start 1 m off, the pass's scale 0.05 % off, a walk of 0.3 m per √km,
#: and, common to every pass, a reference 2 m off and a wheel radius 0.1 % off (wheel wear).
ODOMETRY_ALONE = Positioning(Odometry(1.0, 0.0005, 0.3), common_offset_m=2.0, common_drift=0.001)
#: GNSS-aided: a start 1 m off, the scale 0.01 % off, a walk of 0.1 m per √km, nothing common.
GNSS_AIDED = Positioning(Odometry(1.0, 0.0001, 0.1))

FloatArray = NDArray[np.float64]

#: The features' kinds as an asset register names them (``track.assets.csv``).
REGISTER_KINDS = {"switch": "switch", "crossing": "crossing", "transition": "bridge transition",
                  "level-crossing": "level crossing"}
REGISTER_FIELDS = ("id", "kind", "position_m", "length_m")


def write_register(path: Path, features: list[dict[str, Any]]) -> Path:
    """The track's features as the asset register a railway keeps (``track-map --assets``):
    ids F0, F1, ... (the features' numbers)."""
    return atomic_csv(path, REGISTER_FIELDS, (
        {"id": f"F{r['defect']}", "kind": REGISTER_KINDS.get(str(r["kind"]), str(r["kind"])),
         "position_m": r["position_m"], "length_m": r["length_m"]} for r in features))


#: Columns of a pass's crossings tables (passNN.defects.csv, passNN.features.csv).
CROSSING_FIELDS = ("defect", "kind", "time_s", "duration_s", "center_s", "position_m",
                   "recorded_m", "length_m", "depth_mm", "rail", "channel", "speed_ms")


def layout(fs: float, dated: bool = False) -> Layout:
    """The layout of a physics pass written at ``fs`` Hz (``dated``: with its ``utc`` column,
    seconds since 1970-01-01 UTC)."""
    return Layout(fs=fs, channels=CHANNELS, groups=GROUPS, time="time", speed="speed",
                  position="position", timestamp="utc" if dated else None, latitude="lat",
                  longitude="lon")


def line_of(length_m: float, seed: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The line on the earth (:func:`railwatch.physics.gnss.line`) over a track's extent."""
    return gnss.line(-MARGIN_M, length_m + MARGIN_M, seed)


def _locate(cols: dict[str, FloatArray], true: FloatArray,
            where: tuple[FloatArray, FloatArray, FloatArray], seed: int) -> None:
    """A pass's GNSS fixes (``lat``, ``lon`` columns) where it truly was at ``true``."""
    cols["lat"], cols["lon"] = gnss.fixes(true, np.asarray(cols["time"], dtype=float), where,
                                          seed)


@dataclass(frozen=True)
class Schedule:
    """When the passes run and how the track changes between them: pass ``i`` (from 0) starts
    ``start`` + ``i`` · ``every_days`` (None: undated passes); a share ``growing`` of the squats
    grows, each to a depth ``g`` times its first one at the last pass, ``g`` drawn uniformly
    from ``growth``, linearly in time between, and longer with it (:func:`grown_squat`;
    docs/physics.md, "Dated passes and growing squats")."""

    start: str | None = None
    every_days: float = 7.0
    growing: float = 0.0
    growth: tuple[float, float] = (1.2, 3.0)

    def check(self) -> None:
        if not 0.0 <= self.growing <= 1.0:
            raise RailwatchError(f"--growing {self.growing:g}: give a share of the squats, 0-1")
        if not self.every_days > 0:
            raise RailwatchError(f"--every-days {self.every_days:g}: give a positive number "
                                 "of days between passes")
        if self.start is not None:
            self.start_s()

    def start_s(self) -> float:
        """The first pass's start, seconds since 1970-01-01 UTC."""
        import pandas as pd

        try:
            stamp = pd.Timestamp(str(self.start))
        except ValueError:
            raise RailwatchError(f"--start {self.start}: give a date-time, e.g. "
                                 "2026-01-05T06:00:00Z") from None
        if stamp.tzinfo is None:
            stamp = stamp.tz_localize("UTC")
        return float(stamp.timestamp())

    def growth_of(self, track: PhysicsTrack, seed: int) -> dict[int, float]:
        """Defect index -> its depth at the last pass over its first, for the growing
        squats."""
        squats = [d.index for d in track.defects if d.kind == "squat"]
        rng = np.random.default_rng([seed, 310])
        chosen = sorted(rng.choice(squats, size=int(round(self.growing * len(squats))),
                                   replace=False).tolist()) if squats else []
        return {i: float(rng.uniform(*self.growth)) for i in chosen}


def _grown_for(track: PhysicsTrack, factors: dict[int, float], frac: float) -> PhysicsTrack:
    """The track as pass at time fraction ``frac`` (0: first pass, 1: last) finds it: each
    growing squat ``f`` = 1 + (g - 1) · ``frac`` times as deep, and longer (about its centre)
    as the track's squats are at that depth (:func:`grown_squat`)."""
    if not factors:
        return track
    items = [grown_squat(d, 1.0 + (factors[d.index] - 1.0) * frac, track.world.inventory)
             for d in track.defects if d.index in factors]
    return grown(track, items)


def grown_squat(squat: Item, f: float, inventory: Inventory) -> Item:
    """``squat`` grown ``f`` times as deep and, as the inventory draws its squats (their
    length rises linearly with the log of their depth, from the shortest at the shallowest to
    the longest at the deepest), longer by (longest − shortest) · ln f / ln(deepest /
    shallowest), about its centre: a squat's crack spreads along the rail as the surface
    above it sinks (docs/physics.md, "Dated passes and growing squats")."""
    lo, hi = inventory.squat_depth_mm
    short, long = inventory.squat_length_m
    length = squat.length_m + (long - short) * math.log(f) / math.log(hi / lo)
    return replace(squat, depth_mm=squat.depth_mm * f, length_m=length,
                   position_m=squat.position_m - (length - squat.length_m) / 2)


def write_world(out: str | os.PathLike[str], passes: int, world: World, seed: int = 0,
                plan: PassPlan | None = None, positioning: Positioning = ODOMETRY_ALONE,
                suffix: str = ".parquet",
                progress: Callable[[int], Any] | None = None,
                schedule: Schedule | None = None) -> tuple[PhysicsTrack, list[Path]]:
    """Build ``world``'s track from ``seed`` and simulate ``passes`` passes over it into the
    folder ``out`` (module docstring). Pass ``i`` (from 0) runs along increasing position when
    ``i`` is even and back when odd, each with its own seed (``seed · 1000 + i + 1``), speed
    profile, start and odometry error (``positioning``); ``plan`` gives the rest (its direction
    is ignored). Returns the track and the recordings' paths."""
    if suffix not in FORMATS:
        raise RailwatchError(f"--format {suffix.lstrip('.')}: use csv, parquet, h5 or mat")
    if passes < 1:
        raise RailwatchError(f"--passes must be at least 1, got {passes}")
    plan = plan or PassPlan()
    schedule = schedule or Schedule()
    world.check()
    plan.check()
    schedule.check()
    out = Path(out)
    (out / "twins").mkdir(parents=True, exist_ok=True)
    track = build_track(world, seed)
    factors = schedule.growth_of(track, seed)
    coupling = coupled(world.vehicle, world.track, oversampling(plan.fs) * plan.fs / 2)
    where = line_of(world.length_m, seed)
    dated = schedule.start is not None
    with atomic_path(out / "layout.toml") as tmp:
        tmp.write_text(layout_toml(layout(plan.fs, dated)))
    paths, summaries = [], []
    for i in range(passes):
        pass_seed = seed * 1000 + i + 1
        direction = 1 if i % 2 == 0 else -1
        now = _grown_for(track, factors, i / max(passes - 1, 1))
        p = simulate_pass(now, PassPlan(direction, plan.push_pull, plan.speed_ms, plan.fs),
                          pass_seed, coupling)
        name = f"pass{i + 1:02d}"
        for cols in (p.columns, p.twin):  # from the true positions, before they are recorded
            _locate(cols, np.asarray(p.twin["position"], dtype=float), where, pass_seed)
        _record_positions(p, positioning, pass_seed, seed)
        started = schedule.start_s() + i * schedule.every_days * 86400.0 if dated else None
        if started is not None:
            for cols in (p.columns, p.twin):
                cols["utc"] = started + np.asarray(cols["time"], dtype=float)
        for rows, kind in ((p.crossings, "defects"), (p.features, "features")):
            atomic_csv(out / f"{name}.{kind}.csv", CROSSING_FIELDS, rows)
        write_recording(out / "twins" / f"{name}{suffix}", p.twin)
        paths.append(write_recording(out / f"{name}{suffix}", p.columns))
        summaries.append({"pass": name, "seed": pass_seed, "direction": direction,
                          "minutes": round(float(p.columns["time"][-1]) / 60, 3),
                          "speed_ms": [round(float(p.columns["speed"].min()), 2),
                                       round(float(p.columns["speed"].max()), 2)],
                          "wheel_left_rail_m": [round(x, 2) for x in p.flights_m],
                          "peak_wheel_load": round(p.peak_load, 3), "started_s": started})
        if progress is not None:
            progress(1)
    atomic_csv(out / "track.features.csv", ITEM_FIELDS, [it.row() for it in track.features])
    track = replace(track, defects=[replace(d, params=(*d.params, ("growth", factors[d.index])))
                                    if d.index in factors else d for d in track.defects])
    write_register(out / "track.assets.csv", [it.row() for it in track.features])
    info = {"seed": seed, "passes": summaries, "fs": plan.fs, "speed_ms": list(plan.speed_ms),
            "push_pull": plan.push_pull, "positioning": asdict(positioning),
            "schedule": asdict(schedule),
            "sensor_noise_ms2": dict(zip(CHANNELS, world.sensors.noise().tolist(), strict=True)),
            "world": world.to_dict(), "docs": "docs/physics.md"}
    with atomic_path(out / "physics.json") as tmp:
        tmp.write_text(json.dumps(info, indent=1, default=_plain) + "\n")
    atomic_csv(out / "track.defects.csv", ITEM_FIELDS, [it.row() for it in track.defects])
    return track, paths


def recorded(true: FloatArray, positioning: Positioning, seed: int, folder_seed: int
             ) -> FloatArray:
    """The positions a pass records (m) where it truly was at ``true``: its own errors drawn
    from ``seed``, those every pass shares from ``folder_seed``."""
    travel = np.abs(true - true[0])
    direction = 1 if true[-1] >= true[0] else -1
    common = np.random.default_rng([folder_seed, 210])
    offset = float(common.normal(0.0, positioning.common_offset_m))
    scale = float(common.normal(0.0, positioning.common_drift))
    own = recorded_position(np.random.default_rng([seed, 209]), float(true[0]), travel,
                            direction, positioning.odometry)
    return own + offset + (1 if positioning.odometry.relative else direction) * scale * travel


def _record_positions(p: PhysicsPass, positioning: Positioning, seed: int,
                      folder_seed: int) -> None:
    """Replace the pass's true positions by the recorded ones (its twin keeps the true ones),
    and give each crossing the recorded position of its centre."""
    p.columns["position"] = recorded(p.columns["position"], positioning, seed, folder_seed)
    time = p.columns["time"]
    for row in [*p.crossings, *p.features]:
        row["recorded_m"] = round(float(np.interp(row["center_s"], time,
                                                  p.columns["position"])), 4)


def reposition(folder: str | os.PathLike[str], out: str | os.PathLike[str],
               positioning: Positioning) -> Path:
    """The passes of a simulated ``folder`` positioned by ``positioning`` instead, into ``out``
    (each pass's own errors and the common ones drawn again; recordings rewritten, the twins
    linked): the same pass GNSS-aided and with an odometer alone."""
    import pandas as pd

    folder, out = Path(folder), Path(out)
    info = json.loads((folder / "physics.json").read_text())
    layout = load_layout(folder / "layout.toml")
    (out / "twins").mkdir(parents=True, exist_ok=True)
    for name in ("layout.toml", "track.features.csv", "track.assets.csv"):
        shutil.copy(folder / name, out / name)
    for entry in info["passes"]:
        name, seed = entry["pass"], int(entry["seed"])
        path = next(p for p in folder.glob(f"{name}.*") if p.suffix.lower() in FORMATS
                    and not p.name.endswith((".defects.csv", ".features.csv")))
        data = _read_columns(path, layout)
        true = _read_columns(folder / "twins" / path.name, layout)["position"]
        data["position"] = recorded(np.asarray(true, dtype=float), positioning, seed,
                                    int(info["seed"]))
        if entry.get("started_s") is not None:
            data["utc"] = float(entry["started_s"]) + np.asarray(data["time"], dtype=float)
        if layout.latitude:  # the same fixes: they do not depend on the odometry
            _locate(data, np.asarray(true, dtype=float),
                    line_of(float(info["world"]["length_m"]), int(info["seed"])), seed)
        write_recording(out / path.name, data)
        twin = out / "twins" / path.name
        if not twin.exists():
            twin.symlink_to((folder / "twins" / path.name).resolve())
        for kind in ("defects", "features"):
            rows = pd.read_csv(folder / f"{name}.{kind}.csv").to_dict("records")
            for row in rows:
                row["recorded_m"] = round(float(np.interp(row["center_s"], data["time"],
                                                          data["position"])), 4)
            atomic_csv(out / f"{name}.{kind}.csv", CROSSING_FIELDS, rows)
    with atomic_path(out / "physics.json") as tmp:
        tmp.write_text(json.dumps({**info, "positioning": asdict(positioning)}, indent=1)
                       + "\n")
    shutil.copy(folder / "track.defects.csv", out / "track.defects.csv")  # last
    return out


def _read_columns(path: Path, layout: Layout) -> dict[str, FloatArray]:
    """Every column of a recording written by :func:`write_world`."""
    chunks = list(Recording(path, layout).chunks())
    data = np.concatenate([c.data for c in chunks])
    cols: dict[str, FloatArray] = {
        "time": np.concatenate([c.time for c in chunks]),
        "speed": np.concatenate([c.speed for c in chunks]),
        "position": np.concatenate([c.position for c in chunks])}
    cols.update({c: data[:, i] for i, c in enumerate(CHANNELS)})
    return cols


def _plain(value: Any) -> Any:
    """JSON for numpy scalars and tuples inside the settings."""
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")
