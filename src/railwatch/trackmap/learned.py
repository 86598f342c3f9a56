"""A register learned from the passes (``track-map --learn-assets``): the places that look like
the line's own assets, proposed for an engineer to confirm.

Without a register, every switch, bridge transition and level crossing of a line is a place on
the map. A place is proposed as an asset when all of these hold:

1. **on nearly every pass**: it answers on at least :data:`SHARE` of the passes that covered it,
   over :data:`MIN_PASSES` passes at least; a pass answers where its score stands above its
   neighbourhood's 95th percentile (the fused map's calibration: p < :data:`ANSWER_P`). Not
   the map's ``passes_seen`` (the pass's top 1 %): a switch, weaker than the line's strongest
   items, answered on every pass of the development tracks and was seen on none;
2. **stable**: not growing (where the passes are dated and the place has a trend);
3. **both rails alike**: the weaker rail's evidence over the place's stretch is at least
   :data:`ALIKE` of the stronger rail's. A switch, a bridge transition, a level crossing or a
   pair of insulated joints changes both rails at one place; a squat, a weld, a dipped joint or
   a broken rail's step lies on one rail, which the other rail's axle box feels only through
   the wheelset.

The third is what tells an asset from a defect that is there on every pass: the first two hold
for every defect that does not grow. On the development tracks (physics tracks 100-105, 12
passes each), the weaker rail's share of the evidence was 0.83-1.00 at the 7 switches on their
own and 0.87-0.97 at the 12 bridge transitions, all learned, and 0.00-0.70 at 151 of the 152
defects (one squat 0.82: learned).

A turnout's **crossing nose** lies on one rail and answers as a dipped joint does (0.35-0.72 of
its rails alike): by its rails it is a defect. It is told by its place instead:

4. **a crossing nose beside its switch**: a place that meets 1 and 2 on one rail is learned as
   the crossing nose of a place learned by 1-3 (``beside``) when it lies within
   :data:`LEAD_M` of it, answers at least as strongly (the wheel's drop at the nose is a
   turnout's largest impact: 1-2.5 mm against the switch toe's 0.3-1 mm in the physics world,
   docs/physics.md), and is the nearest such place, with that switch the nearest learned
   place to it.

On the development lines and tracks (trends lines 500 and 504-506, lines 510-511 made
differently, physics tracks 100-105) this took the assets with a place labelled from 63 % to
90 % (64 of 71: the rest are switches without a place of their own or seen by too few
passes, and the noses beside them), and the defects with a place that a learned asset hides
from 2 to 4 of 313 (two squats within 60 m of a switch or of a squat learned for an asset).
Without the strength condition a bridge transition, stronger than the places beside it, took
the nearest defect (8 of 313).

The proposed register (``MAP.learned-assets.csv``) is a register file: ids ``L1``, ``L2`` ...,
kind ``learned``, ``start_m``/``end_m`` the place's stretch, and why (evidence, passes, rails);
an engineer confirms it, names the kinds, and gives it back with ``--assets``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from railwatch.atomic import atomic_csv
from railwatch.errors import RailwatchError
from railwatch.trackmap.assets import Asset, Register
from railwatch.trackmap.folder import Location, PassEvents
from railwatch.trackmap.fusion import Fused

#: A learned asset answers (p < ANSWER_P against its neighbourhood) on at least this share of
#: the passes that covered it ...
SHARE = 0.9
ANSWER_P = 0.05
#: ... over at least this many passes ...
MIN_PASSES = 4
#: ... and its weaker rail has at least this share of its stronger rail's evidence.
ALIKE = 0.8
#: A place on one rail is a turnout's crossing nose when it lies this near a place on both
#: rails (m): the lead from a switch toe to its crossing nose, where the diverging curve of
#: radius R has moved a gauge G = 1.435 m off the straight rail, sqrt(2 R G) = 23-59 m for
#: turnouts of R = 190-1,200 m (1:7.5 to 1:18.5).
LEAD_M = 60.0
#: The kind a learned asset is given.
LEARNED = "learned"
#: Columns of ``MAP.learned-assets.csv``: a register, with why each asset was proposed.
FIELDS = ("id", "kind", "start_m", "end_m", "place_rank", "evidence", "passes_answered",
          "passes_covered", "rails_alike", "beside")


@dataclass(frozen=True)
class Proposed:
    """A learned asset and the place it was learned from."""

    asset: Asset
    place: Location
    answered: int  # passes on which it answered (p < ANSWER_P)
    covered: int  # passes that covered it
    alike: float  # the weaker rail's evidence over the stronger's
    beside: Location | None = None  # a crossing nose: the place of its switch (noses())


def sides(fused: Fused, passes: list[PassEvents]) -> list[int]:
    """Per row of ``fused.by_kind``, the side of the vehicle its channel sits on (its place
    in its sensor group: a group's channels are its sides, listed alike for every group);
    a one-line error where the map did not keep the rails apart."""
    if (fused.sides.split() or [""])[0] not in ("swap", "keep"):
        raise RailwatchError("--learn-assets tells assets by both rails answering alike: map "
                             "with --sides swap, keep or auto (not group)")
    group_of: dict[str, str] = {}
    for p in passes:
        if p.profile is not None:
            group_of.update(zip(p.profile.channels, p.profile.groups, strict=True))
    side = []
    for name in fused.kinds:
        mates = [c for c in group_of if group_of[c] == group_of.get(name)]
        side.append(mates.index(name) if name in mates else 0)
    if len(set(side)) < 2:
        raise RailwatchError("--learn-assets tells assets by both rails answering alike: the "
                             "scanned channels sit on one side of the vehicle")
    return side


def learn(places: list[Location], fused: Fused, passes: list[PassEvents]) -> list[Proposed]:
    """The reported ``places`` that look like assets (module docstring), by position: those on
    both rails, then the crossing noses beside them (:func:`noses`)."""
    side = np.array(sides(fused, passes))
    out: list[Proposed] = []
    steady: list[Proposed] = []  # every place there on nearly every pass, and not growing
    for p in sorted(places, key=lambda q: q.position_m):
        if p.growing == "yes":
            continue
        lo = int(np.searchsorted(fused.grid, p.start_m))
        hi = max(int(np.searchsorted(fused.grid, p.end_m, side="right")), lo + 1)
        cal = fused.calibrated[:, lo:hi]
        over = np.isfinite(cal).any(axis=1)
        covered = int(over.sum())
        answered = int((np.nanmax(cal[over], axis=1) >= -np.log(ANSWER_P)).sum()) \
            if covered else 0
        if covered < MIN_PASSES or answered < SHARE * covered:
            continue
        ev = fused.by_kind[:, lo:hi].max(axis=1)
        per_side = np.array([ev[side == s].max() for s in sorted(set(side.tolist()))])
        if not np.isfinite(per_side).all() or per_side.max() <= 0:
            continue
        alike = float(per_side.min() / per_side.max())
        proposed = Proposed(Asset("", LEARNED, p.start_m, p.end_m), p, answered, covered, alike)
        (out if alike >= ALIKE else steady).append(proposed)
    out = sorted(out + noses(out, steady), key=lambda pr: pr.place.position_m)
    return [replace(pr, asset=replace(pr.asset, id=f"L{i + 1}")) for i, pr in enumerate(out)]


def noses(both: list[Proposed], one: list[Proposed]) -> list[Proposed]:
    """Of the steady places on one rail (``one``) at least as strong as a place on both rails
    (``both``) and within :data:`LEAD_M` of it, the nearest, where that place is its own
    nearest on both rails: a turnout's crossing nose beside its switch toe, ``beside`` set to
    the switch's place."""
    out: list[Proposed] = []
    for b in both:
        near = [q for q in one if abs(q.place.position_m - b.place.position_m) <= LEAD_M
                and q.place.evidence >= b.place.evidence]
        if not near:
            continue
        q = min(near, key=lambda q: abs(q.place.position_m - b.place.position_m))
        mate = min(both, key=lambda a: abs(a.place.position_m - q.place.position_m))
        if mate is b and all(o.place is not q.place for o in out):
            out.append(replace(q, beside=b.place))
    return out


def register(proposed: list[Proposed]) -> Register:
    """The proposed assets as a register (overlaps cannot arise: places do not overlap)."""
    return Register(tuple(pr.asset for pr in proposed))


def write_learned(path: str | os.PathLike[str], proposed: list[Proposed]) -> Path:
    """``MAP.learned-assets.csv`` (:data:`FIELDS`): a register to confirm and give back with
    ``--assets``; ``beside``: a crossing nose's switch."""
    ids = {id(pr.place): pr.asset.id for pr in proposed}
    return atomic_csv(path, FIELDS, (
        {"id": pr.asset.id, "kind": pr.asset.kind, "start_m": f"{pr.asset.start_m:.2f}",
         "end_m": f"{pr.asset.end_m:.2f}", "place_rank": pr.place.rank,
         "evidence": f"{pr.place.evidence:.2f}", "passes_answered": pr.answered,
         "passes_covered": pr.covered, "rails_alike": f"{pr.alike:.2f}",
         "beside": ids.get(id(pr.beside), "")}
        for pr in proposed))
