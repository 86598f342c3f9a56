"""The work list: the places an inspector should walk to, most urgent first; and :func:`plan`,
which says all that ``track-map`` knows of a map's places (the register's labels, the trends)
before listing them.

From a map's reported places (with the register's labels and the trends where ``track-map``
has them) and the register's asset table, in tiers, each by evidence within:

1. **growing, unexplained**: a candidate defect that gets worse pass after pass;
2. **unexplained**: a candidate defect (no asset there; without a register, every place);
3. **an asset that grows or answers more than its kind**: a switch, joint or transition that
   has changed, or is worse than its like;

and nothing else: a known asset that answers as its kind does and does not grow is the line's
normal state. Each row says why it is there, in words.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from railwatch.atomic import atomic_csv
from railwatch.errors import RailwatchError
from railwatch.trackmap import learned, trends
from railwatch.trackmap.assets import UNEXPLAINED, Labelled, Register, Response, apply, write_assets
from railwatch.trackmap.folder import Location, PassEvents, write_map
from railwatch.trackmap.learned import Proposed
from railwatch.trackmap.maps import TrackMap
from railwatch.trackmap.trends import Dated, with_trends, write_passes
from railwatch.trackmap.welds import GROUP as WELD_GROUP

#: Columns of ``MAP.worklist.csv``.
FIELDS = ("priority", "tier", "position_m", "what", "why", "evidence", "growth",
          "growth_low", "growth_high", "passes_seen", "passes_covered", "last_seen",
          "place_rank")
TIERS = {1: "growing, unexplained", 2: "unexplained", 3: "asset: changed or worse than its kind"}
#: The status of a reported place the work list leaves off: a known asset that answers as its
#: kind does.
AS_ITS_KIND = "asset, as its kind"


@dataclass(frozen=True)
class Item:
    """One row of the work list."""

    tier: int
    place: Location
    why: str


def _num(v: float, fmt: str = "{:.4f}") -> str:
    return "" if not math.isfinite(v) else fmt.format(v)


def worklist(reported: list[Location], responses: Sequence[Response] = ()) -> list[Item]:
    """The work list of a map's ``reported`` places (module docstring); ``responses`` (the
    register's asset table) says which assets answer more than their kind."""
    abnormal = {r.asset.id: r for r in responses if r.abnormal}
    items = []
    for p in reported:
        grows = p.growing == "yes"
        growth = (f"grows x{p.growth:.2f} ({p.growth_low:.2f}-{p.growth_high:.2f}) over the "
                  f"passes, p = {p.trend_p:.3g}") if grows else ""
        seen = (f"a dip in the rails' height, weld test z = {p.weld_z:.1f} over "
                f"{p.passes_covered} passes" if p.group == WELD_GROUP else
                f"seen on {p.passes_seen} of {p.passes_covered} passes, evidence {p.evidence:.1f}")
        if p.asset in ("", UNEXPLAINED):
            items.append(Item(1 if grows else 2, p, "; ".join(filter(None, [growth, seen]))))
        elif grows or p.asset in abnormal:
            odd = abnormal.get(p.asset)
            kind = (f"answers {odd.kind_z:.1f} spreads above the other {p.asset_kind}s"
                    if odd else "")
            items.append(Item(3, p, "; ".join(filter(None, [
                f"{p.asset_kind} {p.asset}", growth, kind, seen]))))
    items.sort(key=lambda it: (it.tier, -(it.place.evidence if math.isfinite(it.place.evidence)
                                          else -math.inf), it.place.rank))
    return items


def write_worklist(path: str | os.PathLike[str], items: list[Item]) -> Path:
    """``MAP.worklist.csv`` (:data:`FIELDS`), most urgent first."""
    rows = []
    for i, it in enumerate(items, start=1):
        p = it.place
        rows.append({"priority": i, "tier": TIERS[it.tier], "position_m": f"{p.position_m:.2f}",
                     "what": "place (no register)" if p.asset == "" else UNEXPLAINED
                     if p.asset == UNEXPLAINED else f"{p.asset_kind} {p.asset}",
                     "why": it.why, "evidence": _num(p.evidence, "{:.2f}"),
                     "growth": _num(p.growth, "{:.3f}"), "growth_low": _num(p.growth_low, "{:.3f}"),
                     "growth_high": _num(p.growth_high, "{:.3f}"),
                     "passes_seen": p.passes_seen, "passes_covered": p.passes_covered,
                     "last_seen": p.last_seen, "place_rank": p.rank})
    return atomic_csv(path, FIELDS, rows)


def status_of(place: Location, items: list[Item]) -> tuple[int | None, str, str]:
    """A reported place's priority on the work list (None: not on it), its status (a tier's
    name, or :data:`AS_ITS_KIND`) and why it is listed."""
    for i, it in enumerate(items, start=1):
        if it.place.rank == place.rank:
            return i, TIERS[it.tier], it.why
    return None, AS_ITS_KIND, ""


@dataclass
class Plan:
    """A map with all that is said of its places: the register's labels and asset table
    (None: no register), the trends over dated passes (None: a votes map; no rows: too few
    dated passes), the work list, and the assets learned from the passes (None: not asked)."""

    labelled: Labelled | None
    dated: Dated | None
    items: list[Item]
    proposed: list[Proposed] | None = None

    @property
    def has_trends(self) -> bool:
        return self.dated is not None and bool(self.dated.rows)


def plan(made: TrackMap, passes: list[PassEvents], register: Register | None,
         asset_tolerance_m: float, reach_m: float, covered: tuple[float, float],
         learn: bool = False) -> Plan:
    """Give ``made``'s places their trends over the dated ``passes`` (the fused map's; within
    ``reach_m``), label them by the ``register`` (its assets on the ``covered`` stretch) or,
    with ``learn``, by the assets learned from the passes (:mod:`railwatch.trackmap.learned`),
    and list what to inspect; ``made``'s places are replaced by the labelled ones."""
    labelled = dated = proposed = None
    if made.fused is not None:
        dated = with_trends(made.places, passes, made.fused, reach_m)
        made.replace_places(dated.places)
    if learn:
        if made.fused is None:
            raise RailwatchError("--learn-assets needs the fused map (--method fused)")
        proposed = learned.learn(made.reported, made.fused, passes)
        register = learned.register(proposed)
    if register is not None:
        labelled = apply(made.places, register, covered, asset_tolerance_m, made.fused)
        made.replace_places(labelled.places)
    items = worklist(made.reported, labelled.responses if labelled else [])
    return Plan(labelled, dated, items, proposed)


def write_plan(out: str | os.PathLike[str], made: TrackMap, done: Plan) -> list[Path]:
    """The map (``out``), its asset table, per-pass table, work list and learned register
    beside it (those there is something for: :func:`outputs`); the paths written."""
    written = [write_map(out, made.places)]
    paths = outputs(out)
    if done.labelled is not None:
        written.append(write_assets(paths["assets"], done.labelled))
    if done.has_trends and done.dated is not None:
        written.append(write_passes(paths["passes"], done.dated))
    written.append(write_worklist(paths["worklist"], done.items))
    if done.proposed is not None:
        written.append(learned.write_learned(paths["learned-assets"], done.proposed))
    return written


def outputs(out: str | os.PathLike[str]) -> dict[str, Path]:
    """The files a map writes beside ``MAP.csv``: ``MAP.assets.csv``, ``MAP.passes.csv``,
    ``MAP.worklist.csv``, ``MAP.learned-assets.csv``."""
    out = Path(out)
    return {k: out.with_name(f"{out.stem}.{k}.csv")
            for k in ("assets", "passes", "worklist", "learned-assets")}


def growing_said(made: TrackMap, done: Plan) -> str:
    """The closing line's part on trends and the work list."""
    text = ""
    if done.has_trends:
        growing = [p.rank for p in made.reported if p.growing == "yes"]
        text += (f"{len(growing)} reported place{'s' if len(growing) != 1 else ''} growing"
                 + (f" (ranks {', '.join(map(str, growing[:8]))}"
                    f"{' ...' if len(growing) > 8 else ''})" if growing else "")
                 + (f", by the {trends.unit(made.fused)}" if made.fused is not None else "")
                 + "; ")
    n = len(done.items)
    return text + f"work list: {n} place{'s' if n != 1 else ''}" + (
        f", {sum(it.tier == 1 for it in done.items)} growing" if done.has_trends else "")
