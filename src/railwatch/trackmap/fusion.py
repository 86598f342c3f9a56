"""Evidence fused across passes: every pass's score along the track, measured against its own
neighbourhood and ranked within the pass, summed over the passes at each place, and judged
against passes shifted at random.

A defect that a detector finds on 60 % of the passes at its event threshold usually still raises
the score on most of the others, just not above the threshold. Counting thresholded events
throws that away; summing each pass's evidence keeps it. Per pass and place:

1. **Profile on the map's grid.** The pass's per-sample scores (``railwatch scan`` keeps them)
   are laid on the map's frame (the pass's alignment, from the events that repeat) and take, per
   grid step, the highest score within ``slack_m`` (the alignment's remaining error).
2. **Calibration**, as a CFAR detector does: the profile is first made local, ``z =
   (value − median) / (90th percentile − median)`` of the same pass's grid values within
   ``window_m`` on either side (a loud stretch of track raises a pass's scores over hundreds of
   metres and its neighbourhood's level and spread with them; a defect, a few metres, moves
   neither), then ranked against the whole pass: ``p`` is the share of the pass's grid values
   whose ``z`` reaches the value here. Nothing is learned and nothing depends on the
   detector's units (``z`` is the same for any score ``a + b·s``, ``b`` > 0). Ranking within
   the neighbourhood instead (this module's first rule) gave every 200-m stretch's own highest
   value the best ``p`` there is, about five places per km per pass; passes shifted at random
   then lined such places up often, and a defect needed four passes of five at the top to pass
   (docs/track-map.md).
3. **Combination** (Stouffer's method): each pass's ``p`` as a normal score ``z = Φ⁻¹(1 −
   p)``, ``S = Σ z / √k`` over the ``k`` passes that covered the place, standard normal under
   independent nulls; the evidence is ``−log10`` of its tail. A defect raises its score a
   little on most passes rather than a lot on a few (docs/track-map.md: most of the defects the
   map missed were in the top 2–10 % of every pass, never at the top), which is what
   Stouffer's sum weighs most; Fisher's ``Σ −ln p`` (the first rule) weighs the few passes at
   the top, and found 60–75 % where Stouffer's finds 70–85 % of a stage-8-like development
   track's defects from 5 passes.
4. **What is significant** is measured, not assumed (the grid values are not independent): the
   same sum with each pass's calibrated profile shifted by a random offset along its own
   stretch of track (a real defect then lines up with nothing) gives the peaks that passes
   without a repeating defect reach; the expected number of false places per km at an evidence
   level is the count of such peaks above it per km and round.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import maximum_filter1d, median_filter, percentile_filter
from scipy.special import log_ndtr, ndtri
from scipy.stats import theilslopes

#: Grid step of the map (m): finer than a sample at 100 Hz and 25 m/s.
STEP_M = 0.25
#: Defaults of the calibration and of the null (m, rounds).
SLACK_M = 1.0
WINDOW_M = 100.0
ROUNDS = 40
#: The local spread is the distance from the median to this percentile of the neighbourhood.
SPREAD_PERCENTILE = 90.0
#: The local level and spread are taken from every this-many grid points (1 m), then
#: interpolated: a median over 800 points at each of 40,000 points per 10 km costs 16 times more
#: and moves slowly anyway.
LOCAL_STRIDE = 4
#: A shift moves a pass by at least this much (m), so that a defect cannot meet itself.
MIN_SHIFT_M = 100.0
#: A pass "sees" a place when its own value there is in the top 1 % of the pass (−ln p of the
#: calibration).
SEEN = -float(np.log(0.01))
#: A place needs this many passes over it to have evidence at all: one pass confirms nothing
#: (a pass's own top is as high as Stouffer's sum gets from one pass, and near the ends of a
#: track, which most passes do not reach, one pass's noise was reported as a place).
MIN_PASSES = 2


@dataclass
class Fused:
    """The fused evidence along the map's grid."""

    grid: NDArray[np.float64]  # (G,) map positions, m
    evidence: NDArray[np.float64]  # (G,) −log10 of the combined tail, 0 where fewer than
    # MIN_PASSES passes covered
    covered: NDArray[np.int64]  # (G,) passes that covered each grid point
    by_kind: NDArray[np.float64]  # (K, G) the evidence of each kind (sensor group) alone
    calibrated: NDArray[np.float64]  # (P, G) each pass's −ln p, its strongest kind (NaN where
    # it did not cover)
    null_levels: NDArray[np.float64]  # evidence levels at which the null was counted
    null_counts: NDArray[np.float64]  # stretches above each level, over all shifted rounds
    null_km: float  # km of track × rounds behind null_counts
    kinds: tuple[str, ...] = ()  # names of by_kind's rows (sensor groups or channels)
    sides: str = ""  # how the track map laid the passes' channels on them (track_map.SIDES)
    pass_x: list[NDArray[np.float64]] = field(default_factory=list)  # each pass's samples at
    # their map positions (set by the track map)
    pass_score: list[NDArray[np.float64]] = field(default_factory=list)  # and their scores
    # (the highest sensor group's)
    pass_band: list[NDArray[np.float64]] = field(default_factory=list)  # and their low band
    # (trends.low_band: set where every pass has one)
    welds: Any = None  # the map's weld layer (trackmap.welds.WeldLayer), set by the track map

    def false_per_km(self, evidence: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Expected places per km at least this strong among passes without a repeating
        defect (from the shifted rounds, at the highest counted level not above it; half a
        place where none reached it)."""
        level = np.atleast_1d(np.asarray(evidence, dtype=float))
        i = np.clip(np.searchsorted(self.null_levels, level, side="right") - 1, 0,
                    len(self.null_levels) - 1)
        return np.maximum(self.null_counts[i], 0.5) / max(self.null_km, 1e-9)

    def level(self, false_per_km: float) -> float:
        """The lowest counted evidence level above which at most ``false_per_km`` places per
        km arise by chance."""
        ok = np.flatnonzero(self.null_counts <= false_per_km * self.null_km)
        return float(self.null_levels[ok[0]]) if len(ok) else float(self.null_levels[-1])


#: The refinement of the alignment by the score profiles (:func:`profile_shifts`): segment
#: length and largest shift (m).
SEGMENT_M = 1000.0
MAX_SHIFT_M = 4.0

#: Evidence levels (−log10 p) at which the null's stretches are counted.
NULL_LEVELS = np.round(np.arange(2.0, 40.0001, 0.05), 2)


def grid_profile(x: NDArray[np.float64], score: NDArray[np.float64], lo: float, n: int,
                 step: float = STEP_M, slack: float = SLACK_M) -> NDArray[np.float64]:
    """The highest score within ``slack`` of each grid point ``lo + i·step`` (NaN outside the
    stretch the samples cover)."""
    ok = np.isfinite(x) & np.isfinite(score)
    x, score = x[ok], score[ok]
    out = np.full(n, -np.inf)
    if not len(x):
        return np.full(n, np.nan)
    idx = np.clip(np.round((x - lo) / step).astype(np.int64), 0, n - 1)
    np.maximum.at(out, idx, score)
    out = maximum_filter1d(out, size=2 * int(round(slack / step)) + 1, mode="nearest")
    first, last = idx.min(), idx.max()
    out[:first], out[last + 1:] = np.nan, np.nan
    return out


def local_scale(profile: NDArray[np.float64], half: int, stride: int = LOCAL_STRIDE,
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per point of a profile's finite values (in order), the median and the
    :data:`SPREAD_PERCENTILE` percentile of the values at every ``stride``-th of them within
    ``half`` points on either side (mirrored at the ends), interpolated linearly between those
    ``stride`` points."""
    v = np.asarray(profile, dtype=float)
    coarse = v[::stride]
    size = 2 * (half // stride) + 1
    level = median_filter(coarse, size=size, mode="mirror")
    top = percentile_filter(coarse, SPREAD_PERCENTILE, size=size, mode="mirror")
    at = np.arange(len(coarse)) * stride
    return np.interp(np.arange(len(v)), at, level), np.interp(np.arange(len(v)), at, top)


def calibrate(profile: NDArray[np.float64], half: int,
              stride: int = LOCAL_STRIDE) -> NDArray[np.float64]:
    """Per point, ``p``: the share of the profile's finite values whose local ``z`` (module
    docstring; :func:`local_scale` over ``half`` points on either side) reaches the one here,
    counting the point itself: (ties and above) / (1 + values). NaN where the profile is NaN
    (and everywhere if it has no finite value); −inf (a grid step no sample reached) takes the
    pass's lowest finite value before the local scaling."""
    profile = np.asarray(profile, dtype=float)
    ok = ~np.isnan(profile)
    out = np.full(len(profile), np.nan)
    v = profile[ok]
    if not len(v):
        return out
    finite = np.isfinite(v)
    if not finite.any():
        return out
    v = np.where(finite, v, v[finite].min())
    level, top = local_scale(v, half, stride)
    z = (v - level) / np.maximum(top - level, 1e-12 * (1.0 + np.abs(level)))
    ordered = np.sort(z)
    out[ok] = (len(z) - np.searchsorted(ordered, z, side="left")) / (len(z) + 1.0)
    return out


def combine(calibrated: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Stouffer's combination of the passes' −ln p (P, G): −log10 of the standard normal tail
    of ``Σ Φ⁻¹(1 − p) / √k`` over the k passes that covered each point (0 where none did);
    and k."""
    ok = np.isfinite(calibrated)
    k = ok.sum(axis=0)
    z = np.where(ok, -ndtri(np.exp(-np.where(ok, calibrated, 0.0))), 0.0)
    total = z.sum(axis=0) / np.sqrt(np.maximum(k, 1))
    evidence = np.where(k > 0, -log_ndtr(-total) / np.log(10.0), 0.0)
    return evidence, k


def runs_above(evidence: NDArray[np.float64], level: float, gap: int) -> list[NDArray[np.int64]]:
    """Grid indices of each stretch where ``evidence`` exceeds ``level``, stretches closer than
    ``gap`` points merged."""
    hits = np.flatnonzero(evidence > level)
    if not len(hits):
        return []
    return np.split(hits, np.flatnonzero(np.diff(hits) > gap) + 1)


def peak_position(fused: Fused, xs: list[NDArray[np.float64]],
                  scores: list[NDArray[np.float64]], run: NDArray[np.int64]) -> float:
    """Where a stretch of high evidence peaks: the median, over the passes that covered it, of
    the position of each pass's highest raw score on the stretch (the calibrated profiles are
    flat-topped: a max filter). All covering passes, not only those at the top of their pass:
    a place that Stouffer's sum finds on a consistent rise may have one pass at the top or
    none, and one pass's highest score may be noise a few metres off (on the development
    tracks, places reported 2–4 m beside a defect: 0.09 → 0.07 false per km)."""
    lo, hi = fused.grid[run[0]] - SLACK_M, fused.grid[run[-1]] + SLACK_M
    at = []
    for x, s in zip(xs, scores, strict=True):
        m = (x >= lo) & (x <= hi) & np.isfinite(s)
        if m.any():
            at.append(float(x[m][np.argmax(s[m])]))
    return float(np.median(at)) if at else float(fused.grid[run[np.argmax(fused.evidence[run])]])


def count_runs(evidence: NDArray[np.float64], levels: NDArray[np.float64],
               gap: int) -> NDArray[np.int64]:
    """For each of the ascending ``levels``, the stretches where ``evidence`` exceeds it
    (stretches closer than ``gap`` points merged, as :func:`runs_above`)."""
    hits = np.flatnonzero(evidence > levels[0])
    values = evidence[hits]
    counts = np.zeros(len(levels), dtype=np.int64)
    for j, level in enumerate(levels):
        keep = hits[values > level]
        if not len(keep):
            break
        counts[j] = 1 + int((np.diff(keep) > gap).sum())
    return counts


def fuse(xs: list[NDArray[np.float64]], scores: list[NDArray[np.float64]],
         tolerance_m: float = 2.0, step_m: float = STEP_M, slack_m: float = SLACK_M,
         window_m: float = WINDOW_M, rounds: int = ROUNDS,
         seed: int = 0, names: tuple[str, ...] = ()) -> Fused:
    """The fused evidence of passes whose per-sample scores ``scores[i]`` ((n,) or (n, K): K
    kinds of evidence, such as sensor groups, each fused on its own and the strongest taken;
    ``names`` names them) lie at map positions ``xs[i]`` (module docstring)."""
    finite = [x[np.isfinite(x)] for x in xs]
    lo = min((float(f.min()) for f in finite if len(f)), default=0.0)
    hi = max((float(f.max()) for f in finite if len(f)), default=0.0)
    n = int(np.floor((hi - lo) / step_m)) + 1
    grid = (lo + step_m * np.arange(n)).astype(np.float64)
    half = int(round(window_m / step_m))
    scores = [np.asarray(s, dtype=float).reshape(len(s), -1) for s in scores]
    kinds = scores[0].shape[1] if scores else 1
    calibrated = np.full((kinds, len(xs), n), np.nan)
    for i, (x, s) in enumerate(zip(xs, scores, strict=True)):
        for k in range(kinds):
            with np.errstate(divide="ignore"):
                calibrated[k, i] = -np.log(calibrate(
                    grid_profile(x, s[:, k], lo, n, step_m, slack_m), half))

    def by_kind(cal: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        both = [combine(c) for c in cal]
        # One pass confirms nothing: no evidence of a kind where fewer than MIN_PASSES passes
        # covered it (passes may lack a kind: a recording without that sensor group).
        evidence = np.array([np.where(k >= MIN_PASSES, e, 0.0) for e, k in both])
        return evidence, np.isfinite(cal).any(axis=0).sum(axis=0)

    kind_evidence, covered = by_kind(calibrated)
    # The null: each pass shifted along its own covered stretch (circularly), every round.
    rng = np.random.default_rng(seed)
    gap = max(1, int(round(tolerance_m / step_m)))
    spans = [np.flatnonzero(np.isfinite(c).any(axis=0)) for c in calibrated.transpose(1, 0, 2)]
    min_shift = int(round(MIN_SHIFT_M / step_m))
    counts = np.zeros(len(NULL_LEVELS))
    for _ in range(rounds):
        shifted = np.full_like(calibrated, np.nan)
        for i, idx in enumerate(spans):
            if not len(idx):
                continue
            lo_i, hi_i = idx[0], idx[-1] + 1
            length = hi_i - lo_i
            shift = int(rng.integers(min_shift, length - min_shift)) \
                if length > 2 * min_shift else int(rng.integers(0, max(length, 1)))
            shifted[:, i, lo_i:hi_i] = np.roll(calibrated[:, i, lo_i:hi_i], shift, axis=-1)
        null, _ = by_kind(shifted)
        counts += count_runs(null.max(axis=0), NULL_LEVELS, gap)
    km = rounds * float((covered >= MIN_PASSES).sum()) * step_m / 1000.0
    with np.errstate(invalid="ignore"):
        strongest = np.fmax.reduce(calibrated, axis=0)  # NaN only where no kind covered
    return Fused(grid=grid, evidence=kind_evidence.max(axis=0), covered=covered,
                 by_kind=kind_evidence, calibrated=strongest,
                 null_levels=NULL_LEVELS, null_counts=counts, null_km=km, kinds=names)


def _normal_scores(calibrated: NDArray[np.float64]) -> NDArray[np.float64]:
    """The positive part of ``Φ⁻¹(1 − p)`` of calibrated profiles (−ln p; 0 where NaN)."""
    ok = np.isfinite(calibrated)
    return np.where(ok, np.maximum(-ndtri(np.exp(-np.where(ok, calibrated, 0.0))), 0.0), 0.0)


def _segments(z: NDArray[np.float64], others: NDArray[np.float64], covered: NDArray[np.bool_],
              reach: int, seg: int) -> Iterator[tuple[int, int, NDArray[np.float64]]]:
    """Per ``seg`` grid points of the ``covered`` stretch: its first and last point and the
    correlation of ``z`` with ``others`` shifted by −``reach`` .. ``reach`` points."""
    idx = np.flatnonzero(covered)
    if not len(idx):
        return
    for s0 in range(idx[0] + reach, idx[-1] - reach - seg // 2, seg):
        s1 = min(s0 + seg, idx[-1] - reach)
        yield s0, s1, np.array([np.dot(z[s0:s1], others[s0 + k:s1 + k])
                                for k in range(-reach, reach + 1)])


def agreement(calibrated: NDArray[np.float64], others: NDArray[np.float64], reach: int,
              seg: int) -> float:
    """How well a pass's calibrated profile (−ln p) lies on ``others`` (the other passes' sum
    of normal scores): per segment the highest correlation within ``reach`` points, summed."""
    z, covered = _normal_scores(calibrated), np.isfinite(calibrated)
    return float(sum(max(float(c.max()), 0.0)
                     for _, _, c in _segments(z, others, covered, reach, seg)))


def keeps_move(xs: list[NDArray[np.float64]], scores: list[NDArray[np.float64]],
               recorded: list[NDArray[np.float64]], max_shift_m: float = MAX_SHIFT_M,
               segment_m: float = SEGMENT_M) -> list[bool]:
    """Per pass, whether its placement ``xs[i]`` lays its calibrated profile on the other
    passes' (their sum, all at ``xs``) at least as well as its recorded positions
    ``recorded[i]`` do (:func:`agreement`, each ``segment_m`` at its best shift within
    ``max_shift_m``). Events above a threshold are a few per km, and on wheel-periodic impulses
    they repeat at every wheel turn: chance pairs can pull a pass tens of metres (on a
    development track one of five passes recorded within 3 m of the truth was moved 15–58
    m); every defect raises a pass's profile, events or not, so the profiles can tell."""
    fused = fuse(xs, scores, rounds=0)
    z = _normal_scores(fused.calibrated)
    total = z.sum(axis=0)
    reach, seg = int(round(max_shift_m / STEP_M)), int(round(segment_m / STEP_M))
    lo, n = float(fused.grid[0]), len(fused.grid)
    half = int(round(WINDOW_M / STEP_M))
    out = []
    for i, (x, s, r) in enumerate(zip(xs, scores, recorded, strict=True)):
        if np.array_equal(x, r):
            out.append(True)
            continue
        others = total - z[i]
        s = np.asarray(s, dtype=float).reshape(len(s), -1)
        inside = (r >= lo) & (r <= fused.grid[-1])
        with np.errstate(divide="ignore", invalid="ignore"):
            alt = np.fmax.reduce([-np.log(calibrate(grid_profile(r[inside], s[inside, k], lo, n),
                                                    half)) for k in range(s.shape[1])], axis=0)
        out.append(agreement(fused.calibrated[i], others, reach, seg)
                   >= agreement(alt, others, reach, seg))
    return out


def profile_shifts(xs: list[NDArray[np.float64]], scores: list[NDArray[np.float64]],
                   max_scale_error: float, segment_m: float = SEGMENT_M,
                   max_shift_m: float = MAX_SHIFT_M) -> list[tuple[float, float]]:
    """Per pass, the correction ``x ↦ x + c0 + c1·x`` that lays its calibrated profile best on
    the other passes' (their sum), within ``max_shift_m``: the alignment by events uses only
    the few events per km above a threshold; a pass's profile carries every defect that raises
    its scores, events or not. Per ``segment_m`` of the pass's stretch, the shift of highest
    correlation between the pass's normal scores (``Φ⁻¹(1 − p)``, the positive part) and the
    others' sum (to a fraction of a grid step by a parabola through the peak); a robust line
    through the segments' shifts (Theil–Sen, its slope within ``max_scale_error``). ``(0, 0)``
    for a pass with fewer than three segments whose peak lies inside the search."""
    fused = fuse(xs, scores, rounds=0)
    z = _normal_scores(fused.calibrated)
    total = z.sum(axis=0)
    reach, seg = int(round(max_shift_m / STEP_M)), int(round(segment_m / STEP_M))
    out = []
    for i in range(len(xs)):
        centres, shifts = [], []
        for s0, s1, c in _segments(z[i], total - z[i], np.isfinite(fused.calibrated[i]),
                                   reach, seg):
            k = int(np.argmax(c))
            if c[k] <= 0 or k in (0, 2 * reach):  # nothing in common, or at the edge
                continue
            curve = c[k - 1] - 2 * c[k] + c[k + 1]
            frac = 0.5 * (c[k - 1] - c[k + 1]) / curve if curve < 0 else 0.0
            centres.append(float(fused.grid[(s0 + s1) // 2]))
            shifts.append((k - reach + frac) * STEP_M)
        if len(shifts) < 3:
            out.append((0.0, 0.0))
            continue
        slope = float(np.clip(theilslopes(shifts, centres)[0], -max_scale_error,
                              max_scale_error))
        c0 = float(np.median(np.asarray(shifts) - slope * np.asarray(centres)))
        out.append((c0, slope))
        # The next passes are laid on this one where it now lies (Gauss–Seidel: moving every
        # pass at once towards the others as they were overshoots and oscillates).
        moved = np.interp(fused.grid - (c0 + slope * fused.grid), fused.grid, z[i])
        total += moved - z[i]
        z[i] = moved
    return out
