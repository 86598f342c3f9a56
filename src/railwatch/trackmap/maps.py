"""From repeated passes to a track map: passes aligned by the events that repeat, then places
ranked either by the evidence fused from every pass's scores (:func:`fused_map`, the default:
:mod:`railwatch.trackmap.fusion`) or by how many of the passes that covered a place had an
event there (:func:`track_map`, the votes, described below).

A real defect shows up at the same track position on pass after pass (at different speeds and
noise levels); a false event does not. The map turns the events of many recordings of one line
(``railwatch scan``) into locations:

1. **Alignment** (:mod:`railwatch.trackmap.align`): each pass's odometry laid on the others'
   by the events that repeat.
2. **Clustering.** Aligned events closer than ``tolerance_m`` are one location (single linkage:
   the connected groups of the "closer than" graph).
3. **Per location:** position (median), extent, passes seen, passes that covered it (their
   aligned position range), the share, a confidence (the 95 % Wilson lower bound of seen /
   covered, so 9 of 10 ranks above 1 of 1 and above 1 of 10), median score, dominant channel and
   group, a kind guess from the events' duration, first and last recording seen.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.errors import RailwatchError
from railwatch.trackmap import fusion, welds
from railwatch.trackmap.align import align, refine_by_profiles, verify_moves
from railwatch.trackmap.folder import Location, PassEvents, ScoreProfile, started_time

#: Passes with an event over a fused place that it needs, by the scale of the scanning model
#: (docs/track-map.md, "Evidence and events"). At field scale a rail's own texture (its
#: supports, roughness and irregularity) raises every pass's score at the same places, so that
#: agreement below the event threshold alone is no evidence of a defect: on the development
#: physics tracks the 10-pass maps reported 4.4 such places per km, 0.7 with the rule, at the
#: same recall. The benchmark's synthetic runs have no texture: there a defect below the
#: threshold on every pass is still found.
MIN_EVENTS = {"field": 1, "benchmark": 0}
#: Events up to this long (s) look like a spike, longer ones like a local deviation. An event
#: lasts longer than its defect (the windows around it score too): on context-glr's events of a
#: development track (stage 5, loud stretches) spikes' events last 0.15 / 0.35 / 0.39 s
#: (quartiles), local deviations' 0.42 / 0.47 / 0.55 s; this cut guesses about 3 in 4 right.
SPIKE_LIKE_S = 0.4
#: How a pass's channels are laid on the track before their evidence is summed over the passes
#: (``track-map --sides``): ``swap`` (a vehicle whose sides swap rails when it runs the other
#: way: turned at the line's ends), ``keep`` (a vehicle whose sides stay on their rails:
#: push-pull), ``group`` (each sensor group's highest channel: either), ``auto`` (``swap`` or
#: ``keep``, the one under which the passes agree most: the most evidence summed over the
#: places stronger than chance gives :data:`CHOICE_PER_KM` times per km;
#: docs/notes/2026-12-03-track-map-how-we-got-here.md, "The sides of the vehicle").
SIDES = ("auto", "swap", "keep", "group")
CHOICE_PER_KM = 0.1


def single_linkage(x: NDArray[np.float64], tolerance: float) -> NDArray[np.int64]:
    """Cluster labels of 1-D points: connected groups of the graph |xi − xj| <= tolerance
    (sorted, a gap above ``tolerance`` starts a new group); labels in order of position."""
    order = np.argsort(x, kind="stable")
    gaps = np.diff(x[order]) > tolerance
    labels = np.empty(len(x), dtype=np.int64)
    labels[order] = np.concatenate([[0], np.cumsum(gaps)]) if len(x) else []
    return labels


def _cluster_all(passes: list[PassEvents], transforms: list[tuple[float, float]],
                 tolerance: float) -> tuple[NDArray[np.int64], NDArray[np.float64],
                                            NDArray[np.int64]]:
    xs = np.concatenate([a + b * p.position for p, (a, b) in zip(passes, transforms,
                                                                   strict=True)]) \
        if passes else np.zeros(0)
    owners = np.concatenate([np.full(len(p.position), i) for i, p in enumerate(passes)]) \
        if passes else np.zeros(0, dtype=np.int64)
    return single_linkage(xs, tolerance), xs, owners


def wilson_lower(seen: int, covered: int, z: float = 1.96) -> float:
    """The 95 % Wilson lower bound of the share ``seen / covered``."""
    if covered <= 0:
        return 0.0
    p = seen / covered
    denom = 1 + z * z / covered
    centre = p + z * z / (2 * covered)
    spread = z * math.sqrt(p * (1 - p) / covered + z * z / (4 * covered * covered))
    return max(0.0, (centre - spread) / denom)


def track_map(passes: list[PassEvents], tolerance_m: float = 2.0,
              search_m: float | None = 50.0) -> list[Location]:
    """The locations of the events of ``passes`` (module docstring), most confident first."""
    if tolerance_m <= 0:
        raise RailwatchError(f"--tolerance-m must be positive, got {tolerance_m:g}")
    transforms = align(passes, tolerance_m, search_m)
    labels, xs, owners = _cluster_all(passes, transforms, tolerance_m)
    if not len(xs):
        return []
    scores = np.concatenate([p.score for p in passes])
    durations = np.concatenate([p.duration_s for p in passes])
    channels = [c for p in passes for c in p.channel]
    groups = [g for p in passes for g in p.group]
    spans = [sorted((a + b * p.covered[0], a + b * p.covered[1]))
             for p, (a, b) in zip(passes, transforms, strict=True)]
    order = np.argsort(labels, kind="stable")  # each place's events, in index order
    found = []
    for idx in np.split(order, np.flatnonzero(np.diff(labels[order])) + 1):
        at = float(np.median(xs[idx]))
        seen_by = sorted(set(owners[idx].tolist()))
        covered = sum(lo - tolerance_m <= at <= hi + tolerance_m for lo, hi in spans)
        covered = max(covered, len(seen_by))
        channel = Counter(channels[i] for i in idx).most_common(1)[0][0]
        group = Counter(groups[i] for i in idx).most_common(1)[0][0]
        found.append(dict(
            position_m=at, start_m=float(xs[idx].min()), end_m=float(xs[idx].max()),
            passes_seen=len(seen_by), passes_covered=int(covered),
            share=len(seen_by) / covered, confidence=wilson_lower(len(seen_by), covered),
            evidence=math.nan, false_per_km=math.nan,
            median_score=float(np.median(scores[idx])), channel=channel, group=group,
            kind_guess="spike-like" if np.median(durations[idx]) <= SPIKE_LIKE_S
            else "deviation-like",
            first_seen=passes[seen_by[0]].name, last_seen=passes[seen_by[-1]].name,
            passes_with_event=len(seen_by)))
    found.sort(key=lambda r: (-r["confidence"], -r["median_score"], r["position_m"]))
    return [Location(rank=i + 1, **r) for i, r in enumerate(found)]


def runs_up(x: NDArray[np.float64]) -> bool:
    """Whether a pass at map positions ``x`` (in time order) ran up the map."""
    finite = x[np.isfinite(x)]
    return not len(finite) or bool(finite[-1] >= finite[0])


def rail_scores(profiles: list[ScoreProfile], xs: list[NDArray[np.float64]], sides: str,
                ) -> tuple[tuple[str, ...], tuple[str, ...], list[NDArray[np.float64]]]:
    """What the fused map sums over the passes, by the rule ``sides`` (:data:`SIDES`): the
    names of its kinds of evidence, each kind's sensor group, and per pass its scores (n,
    kinds). ``group``: each sensor group's highest channel; ``keep``: each channel as
    recorded; ``swap``: each channel, a pass down the map (``xs``) with its groups mirrored
    (:meth:`ScoreProfile.on_rails`)."""
    if sides == "group":
        groups = tuple(dict.fromkeys(g for pr in profiles for g in pr.groups))
        return groups, groups, [pr.by_group(groups) for pr in profiles]
    group_of = {c: g for pr in profiles for c, g in zip(pr.channels, pr.groups, strict=True)}
    channels = tuple(group_of)
    return channels, tuple(group_of[c] for c in channels), [
        pr.on_rails(channels, mirrored=sides == "swap" and not runs_up(x))
        for pr, x in zip(profiles, xs, strict=True)]


def _agreement(fused: fusion.Fused, gap: int) -> float:
    """How much the passes agree under one rule of :data:`SIDES`: the summed evidence of the
    places stronger than chance gives :data:`CHOICE_PER_KM` times per km (under the wrong
    rule a defect has the evidence of only the passes that ran its way; counting the places
    instead chose the wrong rule on 1 of the 144 development maps of
    benchmarks/track_map_sides.py, a 10-pass map on which both found nearly every defect)."""
    runs = fusion.runs_above(fused.evidence, fused.level(CHOICE_PER_KM), gap)
    return float(sum(fused.evidence[r].max() for r in runs))


def min_events_for(passes: list[PassEvents]) -> int:
    """The events a fused place needs by default (:data:`MIN_EVENTS`): by the scale of the
    models that scanned the passes, 0 unless every one was a field-scale model."""
    scales = {p.scale for p in passes}
    return MIN_EVENTS["field"] if scales == {"field"} else MIN_EVENTS["benchmark"]


def fused_map(passes: list[PassEvents], tolerance_m: float = 2.0,
              search_m: float | None = 50.0, list_per_km: float = 1.0, sides: str = "auto",
              min_events: int | None = None) -> tuple[list[Location], fusion.Fused]:
    """The places where the evidence fused from every pass's scores (:mod:`fusion`: per pass
    measured against its own neighbourhood and ranked within the pass, per kind of evidence
    summed over the passes) is higher than passes shifted at random reach ``list_per_km``
    times per km and where at least ``min_events`` passes had an event (None:
    :func:`min_events_for`); most evident first. The passes are aligned by their events
    (:func:`align`); ``sides`` (:data:`SIDES`) says how their channels are laid on the
    rails."""
    if min_events is None:
        min_events = min_events_for(passes)
    if min_events < 0:
        raise RailwatchError(f"--min-events must be 0 or more, got {min_events}")
    if tolerance_m <= 0:
        raise RailwatchError(f"--tolerance-m must be positive, got {tolerance_m:g}")
    if sides not in SIDES:
        raise RailwatchError(f"--sides must be one of {', '.join(SIDES)}, got {sides!r}")
    lacking = [p.name for p in passes if p.profile is None]
    if lacking:
        raise RailwatchError(f"{lacking[0]} was scanned without a current score profile (a "
                             "scan before railwatch kept each sample's score from its central "
                             "window): scan again into the same folder (only such recordings "
                             "are redone), or map with --method votes")
    profiles = [p.profile for p in passes if p.profile is not None]
    groups = tuple(dict.fromkeys(g for pr in profiles for g in pr.groups))
    per_group = [pr.by_group(groups) for pr in profiles]
    transforms = align(passes, tolerance_m, search_m, consensus=False)
    if search_m is not None:
        transforms = verify_moves(passes, transforms, per_group)
    transforms = refine_by_profiles(passes, transforms, per_group)
    xs = [a + b * pr.position for pr, (a, b) in zip(profiles, transforms, strict=True)]
    gap = max(1, int(round(tolerance_m / fusion.STEP_M)))
    rules = [sides] if sides != "auto" else \
        ["swap", "keep"] if len({runs_up(x) for x in xs}) > 1 else ["keep"]
    candidates = []
    for rule in rules:
        names, kind_groups, scores = rail_scores(profiles, xs, rule)
        candidates.append((fusion.fuse(xs, scores, tolerance_m, names=names), rule,
                           kind_groups))
    fused, rule, kind_groups = max(candidates, key=lambda c: _agreement(c[0], gap))
    fused.sides = rule
    point = [np.nanmax(pg, axis=1) for pg in per_group]
    fused.pass_x, fused.pass_score = xs, point
    bands = [pr.low_band for pr in profiles]
    fused.pass_band = [b.astype(np.float64) for b in bands if b is not None] if all(
        b is not None for b in bands) else []
    events_at = [a + b * p.position for p, (a, b) in zip(passes, transforms, strict=True)]
    found: list[dict[str, Any]] = []
    for run in fusion.runs_above(fused.evidence, fused.level(list_per_km), gap):
        peak = run[np.argmax(fused.evidence[run])]
        at = fusion.peak_position(fused, xs, point, run)
        lo, hi = fused.grid[run[0]] - fusion.SLACK_M, fused.grid[run[-1]] + fusion.SLACK_M
        strength = np.nanmax(fused.calibrated[:, run], axis=1, initial=-np.inf)
        covering = np.flatnonzero(np.isfinite(fused.calibrated[:, peak]))
        seen_by = [int(i) for i in covering if strength[i] >= fusion.SEEN]
        evented = sum(bool(np.any((events_at[i] >= lo - tolerance_m)
                                  & (events_at[i] <= hi + tolerance_m))) for i in covering)
        if evented < min_events:
            continue
        best = [float(np.max(point[i][(xs[i] >= lo) & (xs[i] <= hi)], initial=-np.inf))
                for i in covering]
        durations = [d for i in seen_by for x, d in zip(events_at[i], passes[i].duration_s,
                                                        strict=True)
                     if lo - tolerance_m <= x <= hi + tolerance_m]
        kind = int(np.argmax(fused.by_kind[:, peak]))
        group = kind_groups[kind]
        # The rail, named by the channel over it on a pass up the map; by the groups'
        # maximum, the channel most of the passes that saw the place had highest there.
        channels = [_channel_at(profiles[i], xs[i], lo, hi, group) for i in seen_by] \
            if rule == "group" else [fused.kinds[kind]]
        covered = len(covering)
        found.append(dict(
            position_m=at, start_m=float(lo), end_m=float(hi),
            evidence=float(fused.evidence[peak]),
            false_per_km=float(fused.false_per_km(fused.evidence[peak])[0]),
            passes_seen=len(seen_by), passes_covered=covered,
            share=len(seen_by) / covered if covered else 0.0,
            confidence=wilson_lower(len(seen_by), covered),
            median_score=float(np.median(best)) if best else math.nan,
            channel=Counter(channels).most_common(1)[0][0] if channels else "",
            group=group,
            kind_guess="" if not durations else "spike-like"
            if np.median(durations) <= SPIKE_LIKE_S else "deviation-like",
            first_seen=passes[seen_by[0]].name if seen_by else "",
            last_seen=passes[seen_by[-1]].name if seen_by else "",
            passes_with_event=evented))
    found.sort(key=lambda r: (-r["evidence"], -r["passes_seen"], -r["median_score"],
                              r["position_m"]))
    fused.welds = welds.weld_layer(profiles, transforms, fused.grid,
                                   [rule == "swap" and not runs_up(x) for x in xs],
                                   [(r["start_m"], r["end_m"]) for r in found])
    if fused.welds is not None:
        found = _with_welds(found, fused.welds, list_per_km, tolerance_m, passes, events_at,
                            xs, point)
    return [Location(rank=i + 1, **r) for i, r in enumerate(found)], fused


def _with_welds(found: list[dict[str, Any]], layer: welds.WeldLayer, list_per_km: float,
                tolerance_m: float, passes: list[PassEvents],
                events_at: list[NDArray[np.float64]], xs: list[NDArray[np.float64]],
                point: list[NDArray[np.float64]]) -> list[dict[str, Any]]:
    """The event layer's places (``found``) with the weld layer's ``z`` over each (and its
    chance, where a weld place lies on one and is the rarer), then the weld layer's own places
    that none of them holds, strongest first (:mod:`welds`)."""
    top = np.nan_to_num(layer.top, nan=-np.inf)
    for r in found:
        near = (layer.grid >= r["start_m"] - fusion.SLACK_M) & \
            (layer.grid <= r["end_m"] + fusion.SLACK_M)
        r["weld_z"] = float(top[near].max()) if near.any() and np.isfinite(
            top[near].max()) else math.nan
    for place in welds.weld_places(layer, list_per_km, welds.SEEN_PER_KM, tolerance_m):
        holding = [r for r in found
                   if r["start_m"] - tolerance_m <= place.position_m <= r["end_m"] + tolerance_m]
        if holding:  # a place either layer reports is reported: its rarer chance counts
            for r in holding:
                r["false_per_km"] = min(r["false_per_km"], place.false_per_km)
            continue
        lo, hi = place.start_m - fusion.SLACK_M, place.end_m + fusion.SLACK_M
        covering = [i for i, x in enumerate(xs) if np.any((x >= lo) & (x <= hi))]
        best = [float(np.max(point[i][(xs[i] >= lo) & (xs[i] <= hi)])) for i in covering]
        seen = [passes[i].name for i in place.seen_by]
        found.append(dict(
            position_m=place.position_m, start_m=place.start_m, end_m=place.end_m,
            evidence=-math.log10(max(place.false_per_km * welds.BLOCK_M / 1000.0, 1e-300)),
            false_per_km=place.false_per_km, passes_seen=len(seen),
            passes_covered=place.passes_covered,
            share=len(seen) / place.passes_covered if place.passes_covered else 0.0,
            confidence=wilson_lower(len(seen), place.passes_covered),
            median_score=float(np.median(best)) if best else math.nan,
            channel=place.channel, group=welds.GROUP, kind_guess="weld-like",
            first_seen=seen[0] if seen else "", last_seen=seen[-1] if seen else "",
            passes_with_event=sum(bool(np.any((events_at[i] >= lo - tolerance_m)
                                              & (events_at[i] <= hi + tolerance_m)))
                                  for i in covering),
            weld_z=place.z))
    return found


def _channel_at(profile: ScoreProfile, x: NDArray[np.float64], lo: float, hi: float,
                group: str) -> str:
    """The channel of ``group`` with the highest score of a pass between map positions ``lo``
    and ``hi``."""
    m = (x >= lo) & (x <= hi)
    mine = np.flatnonzero(np.asarray(profile.groups) == group)
    if not m.any() or not len(mine):
        return ""
    scores = profile.channel_score[m][:, mine]
    return profile.channels[mine[int(np.unravel_index(np.argmax(scores), scores.shape)[1])]]


def reported_fused(locations: list[Location], false_per_km: float = 0.1) -> list[Location]:
    """The places of a fused map whose evidence passes randomly shifted passes reach at most
    ``false_per_km`` times per km."""
    return [loc for loc in locations if loc.false_per_km <= false_per_km]


def reported(locations: list[Location], min_share: float = 0.3,
             n_passes: int = 2) -> list[Location]:
    """The locations a map of ``n_passes`` reports: seen on at least ``min_share`` of the passes
    that covered them, and, with two passes or more, on two of them (one pass confirms
    nothing)."""
    return [loc for loc in locations if loc.share >= min_share
            and (loc.passes_seen >= 2 or n_passes < 2)]


def covered_range(passes: list[PassEvents]) -> tuple[float, float]:
    """The stretch of track the passes covered: the lowest and highest recorded position."""
    if not passes:
        return 0.0, 0.0
    return min(p.covered[0] for p in passes), max(p.covered[1] for p in passes)


@dataclass
class TrackMap:
    """A map of repeated passes (:func:`make_map`): every place, the reported ones, the rule
    that reported them (in words), and for the fused map its evidence and reporting level."""

    places: list[Location]
    reported: list[Location]
    rule: str
    fused: fusion.Fused | None = None
    level: float | None = None

    def replace_places(self, places: list[Location]) -> None:
        """The same places with more said of them (labels, trends), in the same order."""
        shown = {id(p) for p in self.reported}
        self.reported = [q for p, q in zip(self.places, places, strict=True) if id(p) in shown]
        self.places = list(places)


def make_map(passes: list[PassEvents], method: str = "fused", tolerance_m: float = 2.0,
             max_offset_m: float | None = 50.0, sides: str = "auto", min_events: str = "auto",
             false_per_km: float = 0.1, min_share: float = 0.3) -> TrackMap:
    """``railwatch track-map``: the ``fused`` map (:func:`fused_map`, places reported at most
    ``false_per_km`` times per km by chance, with an event on ``min_events`` passes: a number,
    or ``auto``, :func:`min_events_for`) or the ``votes`` map (:func:`track_map`, places seen on
    ``min_share`` of the passes that covered them). ``max_offset_m`` None or 0: any offset."""
    if method == "votes":
        places = track_map(passes, tolerance_m, max_offset_m or None)
        return TrackMap(places, reported(places, min_share, len(passes)),
                        f"seen on >= {min_share:g} of the passes that covered them")
    if method != "fused":
        raise RailwatchError(f"--method {method}: use fused or votes")
    text = min_events.strip().lower()
    if text == "auto":
        need = min_events_for(passes)
    elif text.isdigit():
        need = int(text)
    else:
        raise RailwatchError(f"--min-events {min_events}: give a number of passes (0, 1, "
                             "...) or auto")
    places, fused = fused_map(passes, tolerance_m, max_offset_m or None, sides=sides,
                              min_events=need)
    rule = (f"at most {false_per_km:g} such places per km by chance"
            + (f", an event on {need} pass{'es' if need > 1 else ''} at least" if need else "")
            + f"; sides: {fused.sides}" + (" (auto)" if sides == "auto" else ""))
    return TrackMap(places, reported_fused(places, false_per_km), rule, fused,
                    fused.level(false_per_km))


def by_date(passes: list[PassEvents], since: str | None = None, until: str | None = None,
            ) -> tuple[list[PassEvents], list[PassEvents]]:
    """The passes in the order they were recorded (dated ones by date, then the undated by
    name), and, with ``since`` or ``until`` (ISO 8601 dates or date-times; a date alone runs to
    the end of its day), only the dated passes between them; second, the passes left out."""
    import pandas as pd

    def when(text: str, what: str, end: bool = False) -> pd.Timestamp:
        try:
            stamp = started_time(text)
        except ValueError:
            raise RailwatchError(f"{what} {text}: give a date (2026-03-01) or a date-time "
                                 "(2026-03-01T08:15)") from None
        day_only = len(text.strip()) <= 10
        return stamp + pd.Timedelta(days=1) - pd.Timedelta(seconds=1) if end and day_only \
            else stamp

    ordered = sorted(passes, key=lambda p: (p.started is None, p.started or "", p.name))
    if since is None and until is None:
        return ordered, []
    lo = when(since, "--since") if since else None
    hi = when(until, "--until", end=True) if until else None
    if lo is not None and hi is not None and hi < lo:
        raise RailwatchError(f"--until {until} is before --since {since}")
    kept: list[PassEvents] = []
    left: list[PassEvents] = []
    for p in ordered:
        at = started_time(p.started) if p.started else None
        inside = at is not None and (lo is None or at >= lo) and (hi is None or at <= hi)
        (kept if inside else left).append(p)
    return kept, left


def dates_said(passes: list[PassEvents], left: list[PassEvents]) -> str:
    """What the map's closing line says of the passes' dates."""
    dated = [p.started for p in passes if p.started]
    undated = [p.name for p in passes if not p.started]
    parts = []
    if dated:
        parts.append(f"recorded {dated[0][:10]} to {dated[-1][:10]}")
    if undated and dated:
        parts.append(f"{len(undated)} undated ({', '.join(undated[:3])}"
                     f"{' ...' if len(undated) > 3 else ''})")
    if left:
        parts.append(f"{len(left)} left out by --since/--until"
                     + (" (undated or outside)" if any(not p.started for p in left) else ""))
    return "; ".join(parts)
