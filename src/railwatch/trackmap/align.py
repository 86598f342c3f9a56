"""Aligning repeated passes: each pass's odometry laid on the others' by the events that repeat.

Each pass's recorded positions carry their own odometry error (an offset, a scale error, a slow
walk), and, when they are counted from the pass's own start (no bound on the offset), may run
along the track either way. Each pass in turn gets the linear map ``x ↦ a + b·x`` that lays its
events on those of all the other passes (:func:`fit_transform`: a Hough search over the slope and
offset, then least squares); a real defect is in most passes, so it votes many times where a
false event votes once. A pass is moved only when the move gains more matching events than moves
gain by chance. Where every pass records track positions (all ``b`` > 0), the map's frame is the
median of the passes' odometry. :func:`refine_by_profiles` then refines the moves by the passes'
score profiles (:mod:`railwatch.trackmap.fusion`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from railwatch.trackmap import fusion
from railwatch.trackmap.folder import PassEvents

MAX_SCALE_ERROR = 0.005  # |b| within 1 ± 0.5 %: odometry scale errors are a few per mille
#: A pass is moved only when at least this many of its events (and two more than as recorded)
#: repeat on the reference after the move.
MIN_VOTES = 3


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
