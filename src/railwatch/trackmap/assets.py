"""The asset register: what is known to be on the line, so that the map tells candidate defects
from the switches, crossings, joints and bridge transitions that answer on every pass.

``railwatch track-map --assets ASSETS.csv`` reads a register (:func:`read_assets`), labels every
place of the map with the asset it lies on or ``unexplained`` (:func:`label`), and measures each
asset's response against the other assets of its kind on the same line (:func:`responses`):

- **Labels.** A place lies on an asset when its position is within ``tolerance_m`` of the
  asset's stretch (the map's frame carries the passes' common positioning error: 1.4-2.8 m on
  the physics test tracks with odometry alone, docs/physics.md); the nearest such asset wins.
- **Response.** Per pass, the highest score within the asset's stretch (± ``tolerance_m``), in
  the detector's own units; per pass, its distance from the median of the kind's assets on that
  pass, in the kind's spread on that pass (1.4826 × the median absolute deviation: the pass's
  speed and noise level move every asset of the kind alike, so each pass compares like with
  like); the asset's ``kind_z`` is the median of that over the passes that covered it. An asset
  is **abnormal for its kind** when ``kind_z`` reaches :data:`ABNORMAL_Z` and the line holds at
  least :data:`MIN_OF_KIND` assets of that kind (fewer give no spread to compare with).

The register's own kinds are free text (``switch``, ``crossing``, ``insulated joint``, ``weld``,
``bridge transition``, ``level crossing`` or the user's own), compared in lower case with ``-``
and ``_`` read as spaces.
"""

from __future__ import annotations

import csv
import math
import os
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from railwatch.atomic import atomic_csv
from railwatch.errors import RailwatchError
from railwatch.trackmap.folder import Location
from railwatch.trackmap.fusion import Fused
from railwatch.trackmap.trends import strengths

#: Columns a register may have; others are ignored and named.
COLUMNS = ("id", "kind", "position_m", "length_m", "start_m", "end_m")
#: Assets overlapping by more than this (m) are an error; less is a register's rounding (a
#: turnout's switch written to end where its crossing nose starts, each to 0.1 mm).
OVERLAP_M = 0.01
#: The label of a place on no asset.
UNEXPLAINED = "unexplained"
#: An asset this many of its kind's spreads above the kind's median response is abnormal.
ABNORMAL_Z = 3.5
#: Assets of a kind on the line needed to compare them.
MIN_OF_KIND = 4
#: Columns of the asset table (``MAP.assets.csv``), most abnormal first.
ASSET_FIELDS = ("rank", "id", "kind", "start_m", "end_m", "passes_covered", "response",
                "kind_z", "abnormal", "place_rank")


@dataclass(frozen=True)
class Asset:
    """One row of a register: its id, kind and stretch of track (m)."""

    id: str
    kind: str
    start_m: float
    end_m: float

    def distance(self, x: float) -> float:
        """From a position to this asset's stretch (0 inside it), m."""
        return max(self.start_m - x, x - self.end_m, 0.0)


@dataclass(frozen=True)
class Register:
    """A register as read: its assets (by position) and the columns it ignored."""

    assets: tuple[Asset, ...]
    ignored: tuple[str, ...] = ()


def kind_name(text: str) -> str:
    """A kind as compared: lower case, ``-`` and ``_`` as spaces, single spaces."""
    return " ".join(text.replace("-", " ").replace("_", " ").lower().split())


def read_assets(path: str | os.PathLike[str]) -> Register:
    """A register: one row per asset, a ``kind`` and either ``position_m`` (and ``length_m``,
    0 if absent: a point) or ``start_m`` and ``end_m``; ``id`` optional (the row number)."""
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            fields = [f.strip() for f in reader.fieldnames or []]
            rows = list(reader)
    except OSError as e:
        raise RailwatchError(f"--assets {path}: cannot read it ({e.strerror or e})") from None
    except (UnicodeDecodeError, csv.Error):
        raise RailwatchError(f"--assets {path}: not a CSV text file") from None
    where = "position_m" in fields or {"start_m", "end_m"} <= set(fields)
    if "kind" not in fields or not where:
        raise RailwatchError(f"--assets {path}: a register needs a kind column and either "
                             f"position_m (and length_m) or start_m and end_m; it has "
                             f"{', '.join(fields) or 'no columns'}")
    assets = []
    for n, raw in enumerate(rows, start=2):
        row = {k.strip(): (v or "").strip() for k, v in raw.items() if k is not None}
        kind = kind_name(row.get("kind", ""))
        if not kind:
            raise RailwatchError(f"--assets {path}, line {n}: the kind is empty")
        try:
            if row.get("start_m") and row.get("end_m"):
                lo, hi = float(row["start_m"]), float(row["end_m"])
            else:
                lo = float(row.get("position_m", ""))
                hi = lo + float(row.get("length_m") or 0.0)
        except ValueError:
            raise RailwatchError(f"--assets {path}, line {n}: positions must be numbers of "
                                 "metres (position_m, or start_m and end_m)") from None
        if not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo:
            raise RailwatchError(f"--assets {path}, line {n}: the stretch {lo:g}-{hi:g} m is "
                                 "not a stretch of track (end before start, or not finite)")
        assets.append(Asset(row.get("id") or f"row{n}", kind, lo, hi))
    if not assets:
        raise RailwatchError(f"--assets {path}: the register holds no assets")
    ids = [a.id for a in assets]
    twice = sorted({i for i in ids if ids.count(i) > 1})
    if twice:
        raise RailwatchError(f"--assets {path}: ids must be unique ({', '.join(twice[:3])} "
                             "appear more than once)")
    assets.sort(key=lambda a: (a.start_m, a.end_m))
    for a, b in zip(assets, assets[1:], strict=False):
        if b.start_m < a.end_m - OVERLAP_M:
            raise RailwatchError(f"--assets {path}: assets {a.id} ({a.start_m:g}-{a.end_m:g} m)"
                                 f" and {b.id} ({b.start_m:g}-{b.end_m:g} m) overlap: give "
                                 "each stretch of track to one asset")
    ignored = tuple(f for f in fields if f not in COLUMNS)
    return Register(tuple(assets), ignored)


def on_line(assets: tuple[Asset, ...] | list[Asset], lo: float, hi: float,
            ) -> tuple[list[Asset], list[Asset]]:
    """The assets on the stretch ``[lo, hi]`` the passes covered, and those off it."""
    on = [a for a in assets if a.end_m >= lo and a.start_m <= hi]
    return on, [a for a in assets if not (a.end_m >= lo and a.start_m <= hi)]


def label(positions: NDArray[np.float64] | list[float], assets: list[Asset],
          tolerance_m: float) -> list[Asset | None]:
    """Per position, the nearest asset whose stretch is within ``tolerance_m`` (None: none)."""
    out: list[Asset | None] = []
    for x in np.asarray(positions, dtype=float).reshape(-1):
        best = min(assets, key=lambda a: (a.distance(float(x)), abs(
            0.5 * (a.start_m + a.end_m) - float(x))), default=None)
        out.append(best if best is not None and best.distance(float(x)) <= tolerance_m
                   else None)
    return out


@dataclass(frozen=True)
class Response:
    """An asset's response over the passes (module docstring)."""

    asset: Asset
    passes_covered: int
    response: float  # median over the passes of the highest score on the asset (NaN: none)
    kind_z: float  # median over the passes of its distance from its kind's median, in spreads
    abnormal: bool


def responses(assets: list[Asset], xs: list[NDArray[np.float64]],
              scores: list[NDArray[np.float64]], tolerance_m: float) -> list[Response]:
    """Each asset's response (module docstring) from the passes' scores ``scores[i]`` at map
    positions ``xs[i]``; most abnormal first."""
    peak, _ = strengths(np.array([[a.start_m - tolerance_m, a.end_m + tolerance_m]
                                  for a in assets]).reshape(-1, 2), xs, scores)
    z = np.full_like(peak, np.nan)
    kinds = np.array([a.kind for a in assets])
    for kind in set(kinds.tolist()):
        mine = kinds == kind
        if mine.sum() < MIN_OF_KIND:
            continue
        block = peak[mine]
        with warnings.catch_warnings():  # all-NaN columns: passes that covered none
            warnings.simplefilter("ignore", RuntimeWarning)
            centre = np.nanmedian(block, axis=0)
            spread = 1.4826 * np.nanmedian(np.abs(block - centre), axis=0)
        enough = np.isfinite(block).sum(axis=0) >= MIN_OF_KIND
        spread = np.where(enough & (spread > 0), spread, np.nan)
        z[mine] = (block - centre) / spread
    out = []
    for i, a in enumerate(assets):
        covered = int(np.isfinite(peak[i]).sum())
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            resp = float(np.nanmedian(peak[i])) if covered else math.nan
            kz = float(np.nanmedian(z[i])) if np.isfinite(z[i]).any() else math.nan
        out.append(Response(a, covered, resp, kz, bool(kz >= ABNORMAL_Z)))
    out.sort(key=lambda r: (-(r.kind_z if math.isfinite(r.kind_z) else -math.inf),
                            r.asset.start_m))
    return out



@dataclass
class Labelled:
    """A map's places labelled by a register, and its assets' responses."""

    places: list[Location]
    responses: list[Response]  # the assets on the line, most abnormal first (empty: no scores)
    on_line: list[Asset]
    off_line: list[Asset]

    def place_rank(self, asset: Asset) -> int | None:
        """The rank of the best place on ``asset`` (None: no place)."""
        return min((p.rank for p in self.places if p.asset == asset.id), default=None)


def apply(places: list[Location], register: Register, covered: tuple[float, float],
          tolerance_m: float, fused: Fused | None = None) -> Labelled:
    """Label ``places`` by the register's assets on the ``covered`` stretch of the line, and
    (with a fused map, whose passes' scores it keeps) measure every asset's response."""
    on, off = on_line(register.assets, *covered)
    tags = label([p.position_m for p in places], on, tolerance_m)
    labelled = [replace(p, asset=a.id if a else UNEXPLAINED, asset_kind=a.kind if a else "")
                for p, a in zip(places, tags, strict=True)]
    measured = responses(on, fused.pass_x, fused.pass_score, tolerance_m) \
        if fused is not None and fused.pass_x else []
    return Labelled(labelled, measured, on, off)


def write_assets(path: str | os.PathLike[str], labelled: Labelled) -> Path:
    """The asset table (:data:`ASSET_FIELDS`): every asset on the line with its response, most
    abnormal for its kind first."""
    def num(v: float) -> str:
        return "" if not math.isfinite(v) else f"{v:.4f}"

    rows = []
    for i, r in enumerate(labelled.responses, start=1):
        rank = labelled.place_rank(r.asset)
        rows.append({"rank": i, "id": r.asset.id, "kind": r.asset.kind,
                     "start_m": f"{r.asset.start_m:.4f}", "end_m": f"{r.asset.end_m:.4f}",
                     "passes_covered": r.passes_covered, "response": num(r.response),
                     "kind_z": num(r.kind_z), "abnormal": "yes" if r.abnormal else "no",
                     "place_rank": "" if rank is None else rank})
    return atomic_csv(path, ASSET_FIELDS, rows)


def summary(labelled: Labelled, reported: list[Location], register: Register) -> str:
    """The register's part of ``track-map``'s closing line."""
    on_assets = sum(p.asset not in ("", UNEXPLAINED) for p in reported)
    abnormal = [r.asset.id for r in labelled.responses if r.abnormal]
    text = (f"{len(reported) - on_assets} reported unexplained, {on_assets} on assets "
            f"({len(labelled.on_line)} assets on the line")
    if labelled.off_line:
        text += f", {len(labelled.off_line)} off the stretch the passes covered: left out"
    text += ")"
    if labelled.responses:
        text += (f", {len(abnormal)} abnormal for their kind"
                 + (f" ({', '.join(abnormal[:5])}{' ...' if len(abnormal) > 5 else ''})"
                    if abnormal else ""))
    else:
        text += ", no asset responses (the votes map keeps no scores)"
    if register.ignored:
        text += f"; register columns ignored: {', '.join(register.ignored)}"
    return text
