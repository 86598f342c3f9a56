"""Where the map's places lie on the earth, and the map as GeoJSON or KML that a GIS opens.

**With GNSS** (the recordings' layout names ``latitude`` and ``longitude``: ``scan`` keeps each
pass's route, its fixes at 10 Hz), a map position's latitude and longitude is the median, over
the passes that covered it, of where each pass was when it crossed that position: the map
position gives the pass's sample time there (its samples as the fused map laid them on the
map), the time gives the pass's fix (linear between fixes). Taking the median over passes
averages the fixes' own errors (metres each) down. The line is drawn the same way every
:data:`LINE_STEP_M`.

**Without GNSS** (or on a votes map, which does not lay the passes' samples on the map) a place
has its track position only: GeoJSON then gives it ``"geometry": null`` (RFC 7946, section
3.2, allows a feature without a place on the earth) and its ``track_km``; KML, which has no
such feature, is refused.

Every feature carries the work list's fields (priority, status, why) and the map's (rank,
evidence, asset, growth ...); the GeoJSON also holds the line as a ``LineString`` (``"kind":
"line"``). Coordinates are longitude, latitude (RFC 7946), to 7 decimals (1 cm).
"""

from __future__ import annotations

import json
import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.sax.saxutils import escape

import numpy as np
from numpy.typing import NDArray

from railwatch.atomic import atomic_path
from railwatch.errors import RailwatchError
from railwatch.trackmap.folder import Location, PassEvents
from railwatch.trackmap.maps import TrackMap
from railwatch.trackmap.worklist import Plan, status_of

#: The line's points are this far apart along the map (m).
LINE_STEP_M = 10.0
#: Mean earth radius (m; IUGG): degrees to metres on a sphere's local plane.
EARTH_RADIUS_M = 6_371_008.8
#: What ``--geojson`` writes by the file's suffix.
SUFFIXES = {".geojson": "geojson", ".json": "geojson", ".kml": "kml"}


@dataclass
class Geo:
    """The map on the earth: each reported place's latitude and longitude (NaN: unknown), the
    line as (k, 2) latitude, longitude (empty without GNSS) and how many passes had a route."""

    ranks: list[int]
    lat: NDArray[np.float64]
    lon: NDArray[np.float64]
    line: NDArray[np.float64]
    located: int

    @property
    def on_earth(self) -> bool:
        return self.located > 0 and bool(np.isfinite(self.lat).any() or len(self.line))

    def of(self, ranks: list[int]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Latitude and longitude of the places of these ranks (NaN: unknown)."""
        at = {r: i for i, r in enumerate(self.ranks)}
        idx = np.array([at.get(r, -1) for r in ranks], dtype=int)
        pick = idx >= 0
        lat, lon = np.full(len(ranks), np.nan), np.full(len(ranks), np.nan)
        lat[pick], lon[pick] = self.lat[idx[pick]], self.lon[idx[pick]]
        return lat, lon


def plane(lat: NDArray[np.float64], lon: NDArray[np.float64], lat0: float, lon0: float
          ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Latitude and longitude (degrees) as metres east and north of (``lat0``, ``lon0``), on
    the sphere's local plane (under a millimetre off over a few km)."""
    east = np.radians(np.asarray(lon, dtype=float) - lon0) * EARTH_RADIUS_M * math.cos(
        math.radians(lat0))
    north = np.radians(np.asarray(lat, dtype=float) - lat0) * EARTH_RADIUS_M
    return east, north


def has_route(passes: list[PassEvents]) -> bool:
    """Whether any pass carries its GNSS route (scanned with the layout's latitude and
    longitude)."""
    return any(p.profile is not None and p.profile.route is not None and len(p.profile.route)
               for p in passes)


def at_positions(made: TrackMap, passes: list[PassEvents], x: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    """Latitude and longitude of the map positions ``x`` (module docstring), NaN where no
    pass with a route covered them; and the number of passes with a route."""
    x = np.asarray(x, dtype=float)
    fused = made.fused
    lats, lons, located = [], [], 0
    if fused is not None:
        for j, p in enumerate(passes):
            route = p.profile.route if p.profile is not None else None
            times = p.profile.time_s if p.profile is not None else None
            if route is None or times is None or len(route) < 2 or j >= len(fused.pass_x):
                continue
            located += 1
            px = fused.pass_x[j]
            ok = np.isfinite(px)
            order = np.argsort(px[ok], kind="stable")
            xo, to = px[ok][order], np.asarray(times)[ok][order]
            inside = (x >= xo[0]) & (x <= xo[-1]) if len(xo) else np.zeros(len(x), bool)
            t = np.interp(x, xo, to) if len(xo) else np.full(len(x), np.nan)
            inside &= (t >= route[0, 0]) & (t <= route[-1, 0])
            lats.append(np.where(inside, np.interp(t, route[:, 0], route[:, 1]), np.nan))
            lons.append(np.where(inside, np.interp(t, route[:, 0], route[:, 2]), np.nan))
    if not lats:
        nan = np.full(len(x), np.nan)
        return nan, nan.copy(), located
    with warnings.catch_warnings():  # positions no pass with a route covered
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(lats, axis=0), np.nanmedian(lons, axis=0), located


def locate(made: TrackMap, passes: list[PassEvents], covered: tuple[float, float]) -> Geo:
    """The reported places and the ``covered`` stretch's line on the earth."""
    places = np.array([p.position_m for p in made.reported], dtype=float)
    grid = np.arange(covered[0], covered[1] + LINE_STEP_M / 2, LINE_STEP_M)
    lats, lons, located = at_positions(made, passes, np.concatenate([places, grid]))
    n = len(places)  # one look-up for the places and the line: each pass sorted once
    lat, lon, glat, glon = lats[:n], lons[:n], lats[n:], lons[n:]
    ok = np.isfinite(glat) & np.isfinite(glon)
    return Geo([p.rank for p in made.reported], lat, lon,
               np.stack([glat[ok], glon[ok]], axis=1), located)


def _value(v: Any) -> Any:
    """A field as JSON holds it: NaN as null, floats to 6 decimals (4 gave the
    report double rounding: 1.65499 shown 1.66 beside the work list's 1.65)."""
    if isinstance(v, float):
        return None if not math.isfinite(v) else round(v, 6)
    return v


def properties(place: Location, priority: int | None, status: str, why: str
               ) -> dict[str, Any]:
    """A place's fields in the GeoJSON and the report."""
    return {"priority": priority, "status": status, "why": why, "rank": place.rank,
            "position_m": _value(place.position_m), "track_km": round(place.position_m / 1e3, 5),
            "start_m": _value(place.start_m), "end_m": _value(place.end_m),
            "evidence": _value(place.evidence), "false_per_km": _value(place.false_per_km),
            "passes_seen": place.passes_seen, "passes_covered": place.passes_covered,
            "asset": place.asset, "asset_kind": place.asset_kind,
            "growth": _value(place.growth), "growth_low": _value(place.growth_low),
            "growth_high": _value(place.growth_high), "trend_p": _value(place.trend_p),
            "growing": place.growing, "channel": place.channel, "group": place.group,
            "kind_guess": place.kind_guess, "weld_z": _value(place.weld_z),
            "first_seen": place.first_seen, "last_seen": place.last_seen}


def features(made: TrackMap, done: Plan) -> list[dict[str, Any]]:
    """Every reported place's properties (:func:`properties`), work list first."""
    rows = []
    for place in made.reported:
        priority, status, why = status_of(place, done.items)
        rows.append(properties(place, priority, status, why))
    rows.sort(key=lambda r: (r["priority"] is None, r["priority"] or 0, r["rank"]))
    return rows


def geojson(made: TrackMap, done: Plan, geo: Geo, name: str) -> dict[str, Any]:
    """The map as a GeoJSON FeatureCollection (module docstring)."""
    where = dict(zip(geo.ranks, zip(geo.lat, geo.lon, strict=True), strict=True))
    out: list[dict[str, Any]] = []
    if len(geo.line) >= 2:
        out.append({"type": "Feature", "properties": {"kind": "line"}, "geometry": {
            "type": "LineString",
            "coordinates": [[round(lon, 7), round(lat, 7)] for lat, lon in geo.line]}})
    for props in features(made, done):
        lat, lon = where[props["rank"]]
        point = ({"type": "Point", "coordinates": [round(float(lon), 7), round(float(lat), 7)]}
                 if math.isfinite(lat) and math.isfinite(lon) else None)
        out.append({"type": "Feature", "properties": {"kind": "place", **props},
                    "geometry": point})
    return {"type": "FeatureCollection", "name": name, "features": out}


def kml(made: TrackMap, done: Plan, geo: Geo, name: str) -> str:
    """The map as KML 2.2: the line and every reported place with a position on the earth."""
    where = dict(zip(geo.ranks, zip(geo.lat, geo.lon, strict=True), strict=True))
    marks = []
    if len(geo.line) >= 2:
        coords = " ".join(f"{lon:.7f},{lat:.7f}" for lat, lon in geo.line)
        marks.append(f"<Placemark><name>line</name><LineString><coordinates>{coords}"
                     "</coordinates></LineString></Placemark>")
    for props in features(made, done):
        lat, lon = where[props["rank"]]
        if not (math.isfinite(lat) and math.isfinite(lon)):
            continue
        title = (f"{props['priority']}. " if props["priority"] else "") + (
            f"{props['asset_kind']} {props['asset']}" if props["asset_kind"] else props["status"])
        text = f"{props['status']}; km {props['track_km']:.3f}" + (
            f"; {props['why']}" if props["why"] else "")
        marks.append(f"<Placemark><name>{escape(title)}</name><description>{escape(text)}"
                     f"</description><Point><coordinates>{lon:.7f},{lat:.7f}</coordinates>"
                     "</Point></Placemark>")
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            '<kml xmlns="http://www.opengis.net/kml/2.2"><Document>'
            f"<name>{escape(name)}</name>\n" + "\n".join(marks) + "\n</Document></kml>\n")


def check_out(path: str | os.PathLike[str], passes: list[PassEvents]) -> str:
    """What ``--geojson PATH`` writes (geojson or kml), or a one-line error before any work."""
    name = Path(path).name
    kind = SUFFIXES.get(Path(path).suffix.lower())
    if kind is None:
        raise RailwatchError(f"--geojson {name}: write .geojson (or .json), or .kml")
    if kind == "kml" and not has_route(passes):
        raise RailwatchError(f"--geojson {name}: KML needs positions on the earth, and these "
                             "scans carry no GNSS fixes (name latitude and longitude in the "
                             "layout, then scan again); write .geojson (track km) instead")
    return kind


def write(path: str | os.PathLike[str], made: TrackMap, done: Plan, geo: Geo) -> Path:
    """The map as GeoJSON or KML by ``path``'s suffix (checked first: :func:`check_out`)."""
    path = Path(path)
    if SUFFIXES.get(path.suffix.lower()) == "kml":
        text = kml(made, done, geo, path.stem)
    else:
        text = json.dumps(geojson(made, done, geo, path.stem), allow_nan=False) + "\n"
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return path
