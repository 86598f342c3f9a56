"""The scan folder: every file ``railwatch scan`` writes and the map reads, and the map's CSV.

For every recording ``NAME.EXT`` a scan folder holds ``NAME.events.csv`` (its events, the
columns of ``railwatch detect``), ``NAME.profile.npz`` (every sample's score with its position:
what the fused map sums over passes) and ``NAME.scan.json`` (the recording, the model, the
stretch of track it covered; written last, it marks the recording done); ``events.csv``
combines every recording's events. :mod:`railwatch.trackmap.scan` writes them,
:func:`read_scan` reads them back as :class:`PassEvents`; :func:`write_map` writes a map's
places (:class:`Location`, :data:`MAP_FIELDS`).
"""

from __future__ import annotations

import csv
import json
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.atomic import atomic_csv
from railwatch.errors import RailwatchError

#: What a scan writes per recording beside its events (``<name>.scan.json``).
SCAN_SUFFIX = ".scan.json"
EVENTS_SUFFIX = ".events.csv"
PROFILE_SUFFIX = ".profile.npz"
#: What a scan's score profile holds (``"profile"`` in ``NAME.scan.json``): each sample's score
#: from the window it is most central in. A scan without it kept the maximum over the windows
#: that cover each sample: ``scan`` redoes such recordings, the fused map refuses them.
PROFILE_KIND = "central-window"
#: Columns of the map (one row per location, most confident first).
MAP_FIELDS = ("rank", "position_m", "start_m", "end_m", "evidence", "false_per_km",
              "passes_seen", "passes_with_event", "passes_covered", "share", "confidence",
              "median_score", "channel", "group", "kind_guess", "first_seen", "last_seen",
              "asset", "asset_kind", "growth", "growth_low", "growth_high", "trend_p",
              "growing", "weld_z")
COMBINED = "events.csv"  # every recording's events, a ``recording`` column first
#: The arrays of ``NAME.profile.npz``: each sample's time (s), recorded position (m, NaN
#: without one) and score per channel (n, C), and the channels' names and sensor groups.
PROFILE_ARRAYS = ("time_s", "position_m", "channel_score", "channels", "groups")
#: ... and, where the recording carried GNSS fixes, its route: (k, 3) time (s, as time_s),
#: latitude and longitude (degrees, WGS 84), at 10 Hz (readers.recording_route).
ROUTE_ARRAY = "route"
#: ... and, where the model knows its axle boxes' response, the weld test along the track
#: (recordings.rails.weld_evidence): every 5 cm travelled, the recorded position (m) and the
#: highest ``z`` of the rail under each axle box of the layout's axle group, in its order (k, 2).
WELD_ARRAYS = ("weld_position_m", "weld_z")
#: ... and, for a recording at field rate, each sample's low band (n,): the highest over the
#: axle-box group's channels (every channel's where no group is one) of |acceleration| below
#: trends.BAND_HZ, what a place's trend measures.
BAND_ARRAY = "band"
#: The keys of ``NAME.scan.json``: what was scanned, by which model, how, and the stretch of
#: track it covered (recorded positions of its first and last sample).
SCAN_KEYS = ("recording", "duration_s", "events", "threshold", "detect_s", "position_first_m",
             "position_last_m", "profile", "wheel_turns_m", "scale", "gnss", "model",
             "model_path", "signature", "threshold_given", "scanned", "started")


@dataclass
class ScoreProfile:
    """A recording's per-sample scores along the track (``NAME.profile.npz`` of a scan)."""

    position: NDArray[np.float64]  # (n,) recorded position of each sample, m
    channel_score: NDArray[np.float32]  # (n, C)
    channels: tuple[str, ...]
    groups: tuple[str, ...]
    time_s: NDArray[np.float64] | None = None  # (n,) each sample's time in its recording, s
    route: NDArray[np.float64] | None = None  # (k, 3) time, latitude, longitude (None: no GNSS)
    weld_position: NDArray[np.float64] | None = None  # (k,) recorded positions of the weld
    weld_z: NDArray[np.float32] | None = None  # test, and its z per axle box (k, 2) (None: none)
    low_band: NDArray[np.float32] | None = None  # (n,) each sample's low band (None: none)

    def by_group(self, groups: tuple[str, ...]) -> NDArray[np.float64]:
        """(n, len(groups)): the highest channel score of each sensor group (the side a defect
        is felt on swaps with the direction of travel on some vehicles; its group does not)."""
        g = np.asarray(self.groups)
        return np.stack([self.channel_score[:, g == name].max(axis=1) if (g == name).any()
                         else np.full(len(self.position), np.nan) for name in groups], axis=1)

    def on_rails(self, channels: tuple[str, ...], mirrored: bool) -> NDArray[np.float64]:
        """(n, len(channels)): column j the score of the channel that was over channel j's
        rail: channel j itself or, ``mirrored`` (a pass the other way on a vehicle whose sides
        swap with its direction), the channel at the mirror place of j's sensor group (the
        group's channels in reverse order: a group's channels are its sides). NaN for a
        channel this recording lacks."""
        own = {name: i for i, name in enumerate(self.channels)}
        source = np.arange(len(self.channels))
        if mirrored:
            g = np.asarray(self.groups)
            for name in dict.fromkeys(self.groups):
                idx = np.flatnonzero(g == name)
                source[idx] = idx[::-1]
        nan = np.full(len(self.position), np.nan)
        return np.stack([self.channel_score[:, source[own[c]]].astype(np.float64)
                         if c in own else nan for c in channels], axis=1)


@dataclass
class PassEvents:
    """One recording's events and the stretch of track it covered (recorded positions)."""

    name: str
    position: NDArray[np.float64]  # (n,) event peak positions, m
    score: NDArray[np.float64]  # (n,)
    duration_s: NDArray[np.float64]  # (n,)
    channel: list[str]
    group: list[str]
    covered: tuple[float, float]  # recorded position range of the recording, m
    profile: ScoreProfile | None = None  # every sample's scores (None: a scan without them)
    start: float | None = None  # recorded position of the recording's first sample, m
    scale: str = ""  # the scale of the model that scanned it ("" : a scan before the key)
    started: str | None = None  # when the recording began (ISO 8601; None: undated)


@dataclass(frozen=True)
class Location:
    rank: int
    position_m: float
    start_m: float
    end_m: float
    evidence: float  # fused: −log10 of the combined tail (NaN for the votes method)
    false_per_km: float  # fused: places this strong expected per km by chance (NaN: votes)
    passes_seen: int
    passes_covered: int
    share: float
    confidence: float
    median_score: float
    channel: str
    group: str
    kind_guess: str
    first_seen: str
    last_seen: str
    passes_with_event: int = 0  # passes with an event over the place (votes: passes_seen)
    asset: str = ""  # with a register (track-map --assets): the asset's id or "unexplained"
    asset_kind: str = ""
    growth: float = math.nan  # over dated passes (trackmap.trends): the fitted strength at the
    growth_low: float = math.nan  # last pass over the first's, its 95 % interval,
    growth_high: float = math.nan
    trend_p: float = math.nan  # the chance of a trend this strong in passes in random order,
    growing: str = ""  # and "yes" below trends.GROWING_P ("no"; "": no trend)
    weld_z: float = math.nan  # the map's weld layer there (trackmap.welds; NaN: no weld test)


def started_time(text: str) -> Any:
    """A pass's ``started`` (ISO 8601) as a ``pandas.Timestamp`` to compare with others: a time
    with a zone in UTC with the zone dropped (``scan`` writes UTC with ``Z``), one without as it
    is. Raises ``ValueError`` on text that is not a date-time."""
    import pandas as pd

    stamp = pd.Timestamp(text)
    return stamp.tz_convert("UTC").tz_localize(None) if stamp.tzinfo is not None else stamp


# ----------------------------------------------------------------------------- reading
def read_scan(folder: str | os.PathLike[str]) -> list[PassEvents]:
    """Every recording of a scan folder (``railwatch scan --out``), in name order."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RailwatchError(f"--events {folder}: not a folder (give the --out of "
                             "'railwatch scan')")
    infos = sorted(folder.glob(f"*{SCAN_SUFFIX}"))
    if not infos:
        raise RailwatchError(f"{folder} holds no scanned recordings (*{SCAN_SUFFIX}): give the "
                             "--out folder of 'railwatch scan'")
    return [_read_pass(p) for p in infos]


def _read_pass(info_path: Path) -> PassEvents:
    name = info_path.name[: -len(SCAN_SUFFIX)]
    events_path = info_path.with_name(name + EVENTS_SUFFIX)
    try:
        info = json.loads(info_path.read_text())
        lo, hi = info["position_first_m"], info["position_last_m"]
    except (OSError, ValueError, KeyError) as e:
        raise RailwatchError(f"{info_path} is damaged ({e}): scan the recording again") from None
    if lo is None or hi is None:
        raise RailwatchError(f"{name} has no track position (its layout names no position or "
                             "speed column): a map needs positions")
    try:
        with open(events_path, newline="") as fh:
            reader = csv.DictReader(fh)
            missing = {"position_m", "score", "start_s", "end_s", "channel", "group"} - set(
                reader.fieldnames or [])
            if missing:
                raise RailwatchError(f"{events_path} has no {', '.join(sorted(missing))} "
                                     "column(s): it is not an events file of 'railwatch scan'")
            rows = list(reader)
        position = np.array([float(r["position_m"]) for r in rows], dtype=float)
        score = np.array([float(r["score"]) for r in rows], dtype=float)
        duration = np.array([float(r["end_s"]) - float(r["start_s"]) for r in rows],
                            dtype=float)
    except OSError as e:
        raise RailwatchError(f"cannot read {events_path}: {e}") from None
    except ValueError:
        raise RailwatchError(f"{events_path}: position_m, score, start_s and end_s must be "
                             "numbers (an event without a position cannot be mapped)") from None
    return PassEvents(name=name, position=position, score=score, duration_s=duration,
                      channel=[r["channel"] for r in rows], group=[r["group"] for r in rows],
                      covered=(min(lo, hi), max(lo, hi)), start=float(lo),
                      scale=str(info.get("scale", "")), started=info.get("started"),
                      profile=_read_profile(info_path.with_name(name + PROFILE_SUFFIX))
                      if info.get("profile") == PROFILE_KIND else None)


def profile_arrays(time_s: NDArray[np.float64], position_m: NDArray[np.float64],
                   channel_score: NDArray[np.float32], channels: tuple[str, ...],
                   groups: tuple[str, ...], route: NDArray[np.float64] | None = None,
                   weld: tuple[NDArray[Any], NDArray[Any]] | None = None,
                   band: NDArray[Any] | None = None) -> dict[str, NDArray[Any]]:
    """``NAME.profile.npz``'s arrays by their names (:data:`PROFILE_ARRAYS`, and
    :data:`ROUTE_ARRAY` where there is a route, :data:`WELD_ARRAYS` where there is a weld
    test, :data:`BAND_ARRAY` where there is a low band)."""
    values = (np.asarray(time_s, dtype=float), np.asarray(position_m, dtype=float),
              np.asarray(channel_score, dtype=np.float32), np.array(channels), np.array(groups))
    arrays = dict(zip(PROFILE_ARRAYS, values, strict=True))
    if route is not None:
        arrays[ROUTE_ARRAY] = np.asarray(route, dtype=float).reshape(-1, 3)
    if weld is not None:
        arrays[WELD_ARRAYS[0]] = np.asarray(weld[0], dtype=float)
        arrays[WELD_ARRAYS[1]] = np.asarray(weld[1], dtype=np.float32).reshape(-1, 2)
    if band is not None:
        arrays[BAND_ARRAY] = np.asarray(band, dtype=np.float32)
    return arrays


def scan_record(**values: Any) -> dict[str, Any]:
    """``NAME.scan.json``'s content; a key it does not know (:data:`SCAN_KEYS`) is a bug."""
    unknown = sorted(set(values) - set(SCAN_KEYS))
    if unknown:
        raise ValueError(f"not keys of a scan record: {', '.join(unknown)}")
    return {k: values[k] for k in SCAN_KEYS if k in values}


def _read_profile(path: Path) -> ScoreProfile | None:
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as f:
            time_s, position, score, channels, groups = (f[k] for k in PROFILE_ARRAYS)
            route = f[ROUTE_ARRAY] if ROUTE_ARRAY in f.files else None
            weld = [f[k] for k in WELD_ARRAYS] if WELD_ARRAYS[1] in f.files else None
            band = f[BAND_ARRAY] if BAND_ARRAY in f.files else None
            profile = ScoreProfile(position=np.asarray(position, dtype=float),
                                   time_s=np.asarray(time_s, dtype=float),
                                   channel_score=np.asarray(score, np.float32),
                                   channels=tuple(str(c) for c in channels),
                                   groups=tuple(str(g) for g in groups),
                                   route=None if route is None
                                   else np.asarray(route, dtype=float).reshape(-1, 3),
                                   weld_position=None if weld is None
                                   else np.asarray(weld[0], dtype=float),
                                   weld_z=None if weld is None
                                   else np.asarray(weld[1], np.float32).reshape(-1, 2),
                                   low_band=None if band is None
                                   else np.asarray(band, np.float32).reshape(-1))
    except (OSError, ValueError, KeyError) as e:
        raise RailwatchError(f"{path} is damaged ({e}): remove it and its .scan.json, then "
                             "scan again") from None
    if profile.weld_z is not None and profile.weld_position is not None and \
            len(profile.weld_z) != len(profile.weld_position):
        raise RailwatchError(f"{path} is damaged (its weld test does not match its positions): "
                             "remove it and its .scan.json, then scan again")
    if profile.low_band is not None and len(profile.low_band) != len(profile.position):
        raise RailwatchError(f"{path} is damaged (its low band does not match its scores): "
                             "remove it and its .scan.json, then scan again")
    if profile.channel_score.shape != (len(profile.position), len(profile.channels)):
        raise RailwatchError(f"{path} is damaged (its scores do not match its positions and "
                             "channels): remove it and its .scan.json, then scan again")
    return profile


def write_map(path: str | os.PathLike[str], locations: list[Location]) -> Path:
    rows = ({k: ("" if math.isnan(v) else f"{v:.4f}") if isinstance(v, float) else v
             for k, v in asdict(loc).items()} for loc in locations)
    return atomic_csv(path, MAP_FIELDS, rows)
