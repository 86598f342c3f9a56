"""The work list: the places an inspector should walk to, most urgent first.

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
from dataclasses import dataclass
from pathlib import Path

from railwatch.atomic import atomic_csv
from railwatch.trackmap.assets import UNEXPLAINED, Response
from railwatch.trackmap.folder import Location

#: Columns of ``MAP.worklist.csv``.
FIELDS = ("priority", "tier", "position_m", "what", "why", "evidence", "growth",
          "growth_low", "growth_high", "passes_seen", "passes_covered", "last_seen",
          "place_rank")
TIERS = {1: "growing, unexplained", 2: "unexplained", 3: "asset: changed or worse than its kind"}


@dataclass(frozen=True)
class Item:
    """One row of the work list."""

    tier: int
    place: Location
    why: str


def _num(v: float, fmt: str = "{:.4f}") -> str:
    return "" if not math.isfinite(v) else fmt.format(v)


def worklist(reported: list[Location], responses: list[Response] = ()) -> list[Item]:
    """The work list of a map's ``reported`` places (module docstring); ``responses`` (the
    register's asset table) says which assets answer more than their kind."""
    abnormal = {r.asset.id: r for r in responses if r.abnormal}
    items = []
    for p in reported:
        grows = p.growing == "yes"
        growth = (f"grows x{p.growth:.2f} ({p.growth_low:.2f}-{p.growth_high:.2f}) over the "
                  f"passes, p = {p.trend_p:.3g}") if grows else ""
        seen = f"seen on {p.passes_seen} of {p.passes_covered} passes, evidence {p.evidence:.1f}"
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
