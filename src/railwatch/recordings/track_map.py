"""From repeated passes to a track map: passes aligned by the events that repeat, then places
ranked either by the evidence fused from every pass's scores (:func:`fused_map`, the default:
:mod:`railwatch.recordings.fusion`) or by how many of the passes that covered a place had an
event there (:func:`track_map`, the votes, described below).

A real defect shows up at the same track position on pass after pass (at different speeds and
noise levels); a false event does not. The map turns the events of many recordings of one line
(``railwatch scan``) into locations:

1. **Alignment.** Each pass's recorded positions carry their own odometry error (an offset, a
   scale error, a slow walk), and, when they are counted from the pass's own start (no bound
   on the offset), may run along the track either way. Each pass in turn gets the linear map
   ``x ↦ a + b·x`` that lays its events on those of all the other passes
   (:func:`fit_transform`: a Hough search over the slope and offset, then least squares); a
   real defect is in most passes, so it votes many times where a false event votes once. A
   pass is moved only when the move gains more matching events than moves gain by chance.
   Where every pass records track positions (all ``b`` > 0), the map's frame is the median of
   the passes' odometry.
2. **Clustering.** Aligned events closer than ``tolerance_m`` are one location (single linkage:
   the connected groups of the "closer than" graph).
3. **Per location:** position (median), extent, passes seen, passes that covered it (their
   aligned position range), the share, a confidence (the 95 % Wilson lower bound of seen /
   covered, so 9 of 10 ranks above 1 of 1 and above 1 of 10), median score, dominant channel and
   group, a kind guess from the events' duration, first and last recording seen.
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections import Counter
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.atomic import atomic_csv
from railwatch.errors import RailwatchError
from railwatch.evaluation.crossings import score_places
from railwatch.recordings import fusion

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
              "median_score", "channel", "group", "kind_guess", "first_seen", "last_seen")
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
#: places stronger than chance gives :data:`CHOICE_PER_KM` times per km; docs/track-map.md,
#: "The sides of the vehicle").
SIDES = ("auto", "swap", "keep", "group")
CHOICE_PER_KM = 0.1
MAX_SCALE_ERROR = 0.005  # |b| within 1 ± 0.5 %: odometry scale errors are a few per mille
#: A pass is moved only when at least this many of its events (and two more than as recorded)
#: repeat on the reference after the move.
MIN_VOTES = 3


@dataclass
class ScoreProfile:
    """A recording's per-sample scores along the track (``NAME.profile.npz`` of a scan)."""

    position: NDArray[np.float64]  # (n,) recorded position of each sample, m
    channel_score: NDArray[np.float32]  # (n, C)
    channels: tuple[str, ...]
    groups: tuple[str, ...]

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
                      scale=str(info.get("scale", "")),
                      profile=_read_profile(info_path.with_name(name + PROFILE_SUFFIX))
                      if info.get("profile") == PROFILE_KIND else None)


def _read_profile(path: Path) -> ScoreProfile | None:
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as f:
            profile = ScoreProfile(position=np.asarray(f["position_m"], dtype=float),
                                   channel_score=np.asarray(f["channel_score"], np.float32),
                                   channels=tuple(str(c) for c in f["channels"]),
                                   groups=tuple(str(g) for g in f["groups"]))
    except (OSError, ValueError, KeyError) as e:
        raise RailwatchError(f"{path} is damaged ({e}): remove it and its .scan.json, then "
                             "scan again") from None
    if profile.channel_score.shape != (len(profile.position), len(profile.channels)):
        raise RailwatchError(f"{path} is damaged (its scores do not match its positions and "
                             "channels): remove it and its .scan.json, then scan again")
    return profile


# ----------------------------------------------------------------------------- alignment
def _nearest(x: NDArray[np.float64], ref: NDArray[np.float64]) -> NDArray[np.float64]:
    """For each ``x``, the nearest value of the sorted ``ref`` (two values at least)."""
    i = np.clip(np.searchsorted(ref, x), 1, len(ref) - 1)
    left, right = ref[i - 1], ref[i]
    return np.where(np.abs(x - left) <= np.abs(right - x), left, right)


def _votes(x: NDArray[np.float64], ref: NDArray[np.float64], b: float, tolerance: float,
           search: float | None, centre: float) -> tuple[int, float]:
    """For slope ``b`` and candidate pairs ``(x_i, ref_i)``: the most pairs that one offset
    ``a`` lays within ``tolerance`` (the densest window of width 2·tolerance among ``ref_i −
    b·x_i``, within ``search`` of the offset that keeps ``centre`` in place when given), and
    that offset."""
    diff = ref - b * x
    if search is not None:
        diff = diff[np.abs(diff - (1 - b) * centre) <= search]
    if not len(diff):
        return 0, 0.0
    diff = np.sort(diff)
    right = np.searchsorted(diff, diff + 2 * tolerance, side="right")
    best = int(np.argmax(right - np.arange(len(diff))))
    return int(right[best] - best), float(np.median(diff[best:right[best]]))


def _pairs(x: NDArray[np.float64], ref: NDArray[np.float64], tolerance: float) -> int:
    """The pairs ``(x_i, ref_j)`` within ``tolerance`` of each other, as recorded (``ref``
    sorted)."""
    return int((np.searchsorted(ref, x + tolerance, side="right")
                - np.searchsorted(ref, x - tolerance, side="left")).sum())


def _hough(x: NDArray[np.float64], ref: NDArray[np.float64], tolerance: float,
           search: float | None) -> tuple[int, float, float]:
    """The slope ``b`` (within :data:`MAX_SCALE_ERROR` of +1, or, with no bound on the offset
    (``search`` None: positions counted from each pass's start), of −1 for a pass counted the
    other way) and offset ``a`` that lay the most pairs ``(a + b·x_i, ref_j)`` within
    ``tolerance`` (:func:`_votes`); ``(pairs, a, b)``. With a bound, the positions are the
    track's, give or take ``search``: a pass turned round would move its ends by the length
    of the track (with 1–2 events per km, chance once turned one round)."""
    span = max(float(np.ptp(x)), 1.0)
    # Slope steps that move the far end by half the tolerance.
    step = max(tolerance / (2 * span), 1e-6)
    grid = np.arange(-MAX_SCALE_ERROR, MAX_SCALE_ERROR + step / 2, step)
    centre = float(np.median(x))
    found = []
    for sign in (1.0,) if search is not None else (1.0, -1.0):
        xi, rj = np.broadcast_arrays(x[:, None], ref[None, :])
        if search is not None:
            # Only pairs that some slope of the grid can bring within the search.
            reach = search + tolerance + MAX_SCALE_ERROR * np.abs(x - centre)[:, None]
            keep = np.abs(ref[None, :] - sign * x[:, None] - (1 - sign) * centre) <= reach
            xi, rj = xi[keep], rj[keep]
        xi, rj = xi.ravel(), rj.ravel()
        found += [(*_votes(xi, rj, sign * (1 + e), tolerance, search, centre), sign * (1 + e))
                  for e in grid]
    return max(found, key=lambda f: (f[0], -abs(abs(f[2]) - 1)))


def chance_gain(x: NDArray[np.float64], ref: NDArray[np.float64], tolerance: float,
                search: float | None) -> int:
    """How many pairs the best move gains over the recorded positions by chance alone: the
    largest gain among the pass's events shifted circularly along their own span by 1/5 ... 4/5
    of it (its defects then meet none of the reference's; the rest of its structure, such as
    events at a regular spacing, stays)."""
    lo, span = float(np.min(x)), max(float(np.ptp(x)), 1.0)
    gains = []
    for share in (0.2, 0.4, 0.6, 0.8):
        z = lo + np.mod(x - lo + share * span, span)
        gains.append(_hough(z, ref, tolerance, search)[0] - _pairs(z, ref, tolerance))
    return max(gains)


def fit_transform(x: NDArray[np.float64], ref: NDArray[np.float64], tolerance: float,
                  search: float | None) -> tuple[float, float]:
    """``(a, b)`` that lays ``a + b·x`` onto the reference positions ``ref`` (the other passes'
    events): a search over the slope and the offset (within ``search``, or any) for the most
    pairs within ``tolerance`` (a Hough transform of the matching pairs, :func:`_hough`), then
    a least-squares line through the matched events.

    The move is taken only when it gains more pairs over the positions as recorded than moves
    gain by chance (:func:`chance_gain`): with a few true events among many false ones, some
    slope and offset always gains a few pairs, and taking it moved passes recorded at their
    true positions by metres. ``(0, 1)`` (as recorded) otherwise, and when the move matches
    fewer than :data:`MIN_VOTES` pairs."""
    ref = np.sort(np.asarray(ref, dtype=float))
    if len(ref) < 2 or not len(x):
        return 0.0, 1.0
    as_is = _pairs(x, ref, tolerance)
    votes, a, b = _hough(x, ref, tolerance, search)
    if votes < max(MIN_VOTES, as_is + 2) or \
            votes - as_is <= chance_gain(x, ref, tolerance, search):
        return 0.0, 1.0
    sign = 1.0 if b > 0 else -1.0
    for _ in range(3):  # least squares through the matched events
        y = a + b * x
        near = _nearest(y, ref)
        ok = np.abs(near - y) <= tolerance
        if ok.sum() < 3 or np.ptp(x[ok]) < 100.0:
            if ok.any():
                a = float(np.median(near[ok] - b * x[ok]))
            break
        b_fit, a_fit = np.polyfit(x[ok], near[ok], 1)
        lo, hi = sorted((sign * (1 - MAX_SCALE_ERROR), sign * (1 + MAX_SCALE_ERROR)))
        b_new = float(np.clip(b_fit, lo, hi))
        a = float(a_fit) if b_new == b_fit else float(np.median(near[ok] - b_new * x[ok]))
        b = b_new
    return a, b


def align(passes: list[PassEvents], tolerance_m: float = 2.0,
          search_m: float | None = 50.0, consensus: bool = True) -> list[tuple[float, float]]:
    """Per pass ``(a, b)``: ``a + b·position`` is the position in the map's frame.

    Each pass in turn is fitted (:func:`fit_transform`) to the events of all the others in
    their current frames, three rounds; a real defect is in most passes, so it votes many times
    where false events vote once. ``search_m`` bounds the offset between two passes' positions
    (None: any offset, for positions that are not the track's, such as a distance counted from
    each pass's start). ``consensus``: in the passes' consensus frame (:func:`_consensus_frame`);
    otherwise in the frame of the passes left where they were recorded.
    """
    n = len(passes)
    transforms = [(0.0, 1.0)] * n
    if n < 2:
        return transforms
    for _ in range(3):
        moved = False
        for i, p in enumerate(passes):
            others = np.concatenate([a + b * q.position for k, (q, (a, b)) in
                                     enumerate(zip(passes, transforms, strict=True)) if k != i])
            a0, b0 = transforms[i]
            # Fit the pass as it stands in the map (its current frame), then compose.
            da, db = fit_transform(a0 + b0 * p.position, others, tolerance_m,
                                   search_m if (a0, b0) == (0.0, 1.0) else tolerance_m * 3)
            if (da, db) != (0.0, 1.0):
                transforms[i] = (da + db * a0, db * b0)
                moved = True
        if not moved:
            break
    if consensus and all(b > 0 for _, b in transforms):
        transforms = _consensus_frame(passes, transforms)
    return transforms


def verify_moves(passes: list[PassEvents], transforms: list[tuple[float, float]],
                 scores: list[NDArray[np.float64]]) -> list[tuple[float, float]]:
    """The moves of :func:`align` (``consensus=False``: unmoved passes are ``(0, 1)``) that the
    score profiles confirm (:func:`fusion.keeps_move`); a pass whose profile agrees with the
    others' better where it was recorded goes back there. Only for recorded positions that
    are the track's (a bounded search)."""
    positions = [p.profile.position for p in passes if p.profile is not None]
    xs = [a + b * x for x, (a, b) in zip(positions, transforms, strict=True)]
    keep = fusion.keeps_move(xs, scores, positions)
    return [t if k else (0.0, 1.0) for t, k in zip(transforms, keep, strict=True)]


def refine_by_profiles(passes: list[PassEvents], transforms: list[tuple[float, float]],
                       scores: list[NDArray[np.float64]], rounds: int = 2,
                       ) -> list[tuple[float, float]]:
    """The transforms of :func:`align` refined by the passes' score profiles
    (:func:`fusion.profile_shifts`, ``rounds`` times), then in the frame of the passes' median
    odometry again. On development tracks with odometry alone, passes that the events left
    3–8 m apart at the far end (too few events above the threshold to move them) came within
    about 2 m."""
    positions = [p.profile.position for p in passes if p.profile is not None]
    for _ in range(rounds):
        xs = [a + b * x for x, (a, b) in zip(positions, transforms, strict=True)]
        shifts = fusion.profile_shifts(xs, scores, MAX_SCALE_ERROR)
        transforms = [(a + c0 + c1 * a, b * (1 + c1))
                      for (a, b), (c0, c1) in zip(transforms, shifts, strict=True)]
    if all(b > 0 for _, b in transforms):
        transforms = _consensus_frame(passes, transforms)
    return transforms


def _consensus_frame(passes: list[PassEvents], transforms: list[tuple[float, float]],
                     ) -> list[tuple[float, float]]:
    """The transforms re-expressed in the frame of the passes' odometry where it is most
    accurate. Where every pass records track positions, no pass is the truth, and an
    odometer's error grows with the distance it has counted since it was set (a wheel radius
    0.05 % off is 5 m after 10 km); so each end of the aligned stretch takes the median of the
    positions recorded there by the passes that started at that end, and an end no pass
    started at the median over all passes (the median, not the mean: one odometer 0.2 % off
    moves the mean of five passes 4 m at the far end, the median little); a line between.
    On eight development tracks with odometry alone, from 5 passes, the median over all
    passes at both ends left the map 2–3 m from the truth on some (recall 45 % where the
    same passes at their true positions gave 92 %; docs/track-map.md). Otherwise the frame
    stays the first pass's orientation and origin."""
    ends = np.array([[a + b * p.covered[0], a + b * p.covered[1]]
                     for p, (a, b) in zip(passes, transforms, strict=True)])
    y = np.array([ends.min(), ends.max()])  # the aligned stretch
    if y[1] - y[0] <= 0:
        return transforms
    at_ends = np.array([(y - a) / b for a, b in transforms])  # (passes, 2) recorded there
    starts = [None if p.start is None else a + b * p.start
              for p, (a, b) in zip(passes, transforms, strict=True)]
    recorded = np.empty(2)
    for end in (0, 1):
        near = [i for i, s in enumerate(starts)
                if s is not None and abs(s - y[end]) < abs(s - y[1 - end])]
        recorded[end] = np.median(at_ends[near or slice(None), end])
    if recorded[1] - recorded[0] <= 0:
        return transforms
    # The map's position m of aligned position y: m = recorded[0] + (y − y0)·slope.
    slope = (recorded[1] - recorded[0]) / (y[1] - y[0])
    shift = recorded[0] - slope * y[0]
    return [(shift + slope * a, slope * b) for a, b in transforms]


# ----------------------------------------------------------------------------- clustering
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
    return [Location(rank=i + 1, **r) for i, r in enumerate(found)], fused


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


# ----------------------------------------------------------------------------- outputs
def write_map(path: str | os.PathLike[str], locations: list[Location]) -> Path:
    rows = ({k: ("" if math.isnan(v) else f"{v:.4f}") if isinstance(v, float) else v
             for k, v in asdict(loc).items()} for loc in locations)
    return atomic_csv(path, MAP_FIELDS, rows)


def read_truth(path: str | os.PathLike[str]) -> NDArray[np.float64]:
    """True defects as stretches of track, (n, 2) start and end in m: a ``position_m`` column
    (where each starts) and, if there is one, ``length_m`` (a track's defects table)."""
    path = Path(path)
    try:
        with open(path, newline="") as fh:
            reader = csv.DictReader(fh)
            if "position_m" not in (reader.fieldnames or []):
                raise RailwatchError(f"{path} needs a position_m column of defect positions")
            rows = list(reader)
        start = np.array([float(r["position_m"]) for r in rows], dtype=float)
        length = np.array([float(r.get("length_m") or 0.0) for r in rows], dtype=float)
    except OSError as e:
        raise RailwatchError(f"cannot read {path}: {e}") from None
    except ValueError:
        raise RailwatchError(f"{path}: position_m and length_m must hold numbers of metres") \
            from None
    return np.stack([start, start + length], axis=1).reshape(-1, 2)


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


def on_stretch(truth: NDArray[np.float64], lo: float, hi: float) -> NDArray[np.float64]:
    """The true defects (:func:`read_truth`) that lie on the stretch ``[lo, hi]``."""
    truth = np.asarray(truth, dtype=float).reshape(-1, 2)
    return truth[(truth[:, 1] >= lo) & (truth[:, 0] <= hi)]


def score_locations(locations: list[Location], truth: NDArray[np.float64], length_m: float,
                    tolerance_m: float = 2.0,
                    features: NDArray[np.float64] | None = None) -> dict[str, float]:
    """Recall of the true defects (stretches ``(start, end)``, or positions) by ``locations``
    (a location within ``tolerance_m`` of a defect's stretch finds it), the locations near no
    true defect (nor, when given, a feature's stretch) per km of ``length_m``, the locations on
    features, the frame's offset and the recall with it taken out
    (:func:`railwatch.evaluation.crossings.score_places`)."""
    truth = np.asarray(truth, dtype=float)
    truth = np.stack([truth, truth], axis=1) if truth.ndim == 1 else truth.reshape(-1, 2)
    at = [loc.position_m for loc in locations]
    s = score_places(at, truth, features, length_m / 1000.0, tolerance_m)
    framed = score_places(at, truth, features, length_m / 1000.0, tolerance_m, remove_frame=True)
    return {"recall": float(s.found.mean()) if len(truth) else math.nan,
            "false_per_km": s.false_per_km, "locations": float(len(locations)),
            "on_features": float(s.on_features), "frame_offset_m": s.frame_offset_m,
            "recall_frame": float(framed.found.mean()) if len(truth) else math.nan}
