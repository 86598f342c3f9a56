"""The recording layout: which columns of a user's file are which sensors, and at what rate.

A small TOML or YAML file (``--layout``), for example::

    fs = 2000.0                 # sampling rate of the file (Hz)
    time = "t"                  # optional: time column (s); checked for gaps and rate
    speed = "speed"             # optional: train speed (m/s), integrated to a track position
    position = "pos"            # optional: track position (m); preferred over speed
    timestamp = "utc"           # optional: when each sample was taken (date-time, or seconds
                                # since 1970-01-01 UTC): dates the recording for the map
    latitude = "lat"            # optional, with longitude: GNSS fixes (degrees, WGS 84): put
    longitude = "lon"           # the track map's places on a real map (track-map --geojson)
    scale = "field"             # optional: "field" (a real rail, the default) or "benchmark"

    [channels]                  # accelerometer columns, in the order the model sees them,
    axle_left = "axle"          # each with its sensor group
    axle_right = "axle"
    bogie_left = "bogie"
    bogie_right = "bogie"
    body_left = "body"
    body_right = "body"

``channels`` may also be a plain list of names (groups then default to ``"sensor"``). A name is a
column (CSV, Parquet), a dataset path (HDF5, e.g. ``"acc/axle_left"``) or a variable (MATLAB).

``scale`` says how long a defect lasts in the file: ``"field"`` (the default) is a real rail,
where a 2-10 cm defect is crossed in milliseconds; ``"benchmark"`` marks the recordings of
``railwatch generate-run``, whose defects are the benchmark's, twenty times longer (a 10-ms spike,
0.05-0.2-s boxes). ``train`` chooses its preparation by it (``docs/recordings.md``).
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, replace
from typing import Any

from railwatch.errors import RailwatchError
from railwatch.mapping_files import read_mapping

KEYS = ("fs", "channels", "time", "speed", "position", "timestamp", "latitude", "longitude",
        "scale")
#: The optional columns a layout may name besides the channels.
NAMED = ("time", "speed", "position", "timestamp", "latitude", "longitude")
SCALES = ("field", "benchmark")


@dataclass(frozen=True)
class Layout:
    """Where the data are in a recording file."""

    fs: float  # Hz
    channels: tuple[str, ...]
    groups: tuple[str, ...]
    time: str | None = None
    speed: str | None = None
    position: str | None = None
    scale: str = "field"
    timestamp: str | None = None  # read once, for the recording's start (recording_start)
    latitude: str | None = None  # GNSS fixes, degrees: read by readers.recording_route
    longitude: str | None = None

    @property
    def columns(self) -> tuple[str, ...]:
        """Every column to read: channels, then time, speed and position where named."""
        extra = tuple(c for c in (self.time, self.speed, self.position) if c)
        return self.channels + extra

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["channels"], d["groups"] = list(self.channels), list(self.groups)
        if self.scale == "field":  # the default: model files written before it stay the same
            del d["scale"]
        for key in ("timestamp", "latitude", "longitude"):  # the same
            if d[key] is None:
                del d[key]
        return d

    def select(self, groups: tuple[str, ...]) -> Layout:
        """The layout of the channels of ``groups`` only (in their order)."""
        keep = [i for i, g in enumerate(self.groups) if g in groups]
        if not keep:
            raise RailwatchError(f"no channel of group {', '.join(groups)}: the layout's groups "
                                 f"are {', '.join(dict.fromkeys(self.groups))}")
        return replace(self, channels=tuple(self.channels[i] for i in keep),
                       groups=tuple(self.groups[i] for i in keep))

    @classmethod
    def from_dict(cls, values: dict[str, Any], source: str = "layout") -> Layout:
        return parse_layout(values, source)


def parse_layout(values: Any, source: str = "layout") -> Layout:
    """Validate a layout mapping; every problem is one line naming the key."""
    if not isinstance(values, dict):
        raise RailwatchError(f"{source}: a layout is a table of keys ({', '.join(KEYS)})")
    unknown = sorted(set(values) - set(KEYS) - {"groups"})
    if unknown:
        raise RailwatchError(f"{source}: unknown key(s) {', '.join(unknown)}; "
                             f"valid: {', '.join(KEYS)}")
    if "fs" not in values:
        raise RailwatchError(f"{source}: 'fs' (the file's sampling rate in Hz) is required")
    try:
        fs = float(values["fs"])
    except (TypeError, ValueError):
        raise RailwatchError(f"{source}: fs must be a number of Hz, got {values['fs']!r}") from None
    if not fs > 0:
        raise RailwatchError(f"{source}: fs must be positive, got {fs}")
    raw = values.get("channels")
    if isinstance(raw, dict):
        channels = tuple(str(k) for k in raw)
        groups = tuple(str(v) for v in raw.values())
    elif isinstance(raw, list | tuple) and raw:
        channels = tuple(str(c) for c in raw)
        given = values.get("groups")
        groups = tuple(str(g) for g in given) if given else ("sensor",) * len(channels)
        if len(groups) != len(channels):
            raise RailwatchError(f"{source}: {len(groups)} groups for {len(channels)} channels")
    else:
        raise RailwatchError(f"{source}: 'channels' must list the accelerometer columns "
                             "(a list of names, or a table name = group)")
    if len(set(channels)) != len(channels):
        raise RailwatchError(f"{source}: a channel is named twice")
    named = {k: (str(values[k]) if values.get(k) else None)
             for k in NAMED}
    clash = [v for v in named.values() if v in channels]
    if clash:
        raise RailwatchError(f"{source}: column {clash[0]!r} is both a channel and one of "
                             f"{'/'.join(NAMED)}")
    if bool(named["latitude"]) != bool(named["longitude"]):
        raise RailwatchError(f"{source}: name both latitude and longitude (GNSS fixes), or "
                             "neither")
    scale = str(values.get("scale", "field"))
    if scale not in SCALES:
        raise RailwatchError(f"{source}: scale is {scale!r}: use \"field\" (a real rail) or "
                             "\"benchmark\" (generate-run's recordings)")
    return Layout(fs=fs, channels=channels, groups=groups, **named, scale=scale)


def load_layout(path: str | os.PathLike[str]) -> Layout:
    """Read a layout file (``.toml``, ``.yaml``/``.yml`` or ``.json``)."""
    return parse_layout(read_mapping(path, "layout"), str(path))


def layout_toml(layout: Layout) -> str:
    """The layout as a TOML file (what :func:`load_layout` reads back)."""
    lines = [f"fs = {layout.fs!r}"]
    for key in NAMED:
        value = getattr(layout, key)
        if value:
            lines.append(f"{key} = {json.dumps(value)}")
    if layout.scale != "field":
        lines.append(f"scale = {json.dumps(layout.scale)}  # defects 20x longer than on a "
                     "real rail: the benchmark's")
    lines += ["", "[channels]"]
    lines += [f"{json.dumps(c)} = {json.dumps(g)}" for c, g in zip(layout.channels, layout.groups,
                                                                   strict=True)]
    return "\n".join(lines) + "\n"
