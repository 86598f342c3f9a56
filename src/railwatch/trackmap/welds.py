"""The map's weld layer: the weld test on the rails' height (``scan`` keeps it for every pass,
:mod:`railwatch.recordings.rails`), fused over the passes.

The event layer (:mod:`railwatch.trackmap.fusion`) asks whether a place's scores rise together
on pass after pass more often than passes shifted at random would let them. The weld test
measures the rails' height, which is the same on every pass, its texture included: passes
shifted at random are no null for it, and its null is its own distribution along the line.

1. **Each pass on the map's grid**: its ``z`` on each rail (the axle box over it: mirrored on a
   pass down the map when the vehicle's sides swap with its direction, as the event layer's
   channels), the highest within :data:`~railwatch.trackmap.fusion.SLACK_M` of each grid point
   (the alignment's remaining error). First each pass's ``z`` is judged against its own
   stretch: where the spread of ``z`` over :data:`SPREAD_M` on either side (median to 75th
   percentile) is r times the pass's typical spread, ``z`` is drawn to the pass's median by
   r where r is 2 or more (by less, down to nothing, as r falls to 1). The test is whitened
   by the pass's own spectra, and a stretch run at another speed can hold more than they say
   (on a track run at 5-12 m/s, its 10-12 m/s stretches spread 10-15 times wider, and gave
   3.8 false places per km); a weld, a metre long, does not move an 80-m stretch's
   quartiles.
2. **Fused**: each rail's median over the passes that cover a place, two at least. The texture
   is the same on every pass, so the median does not lower it; it does remove what one pass
   alone had (a bad stretch of signal, a wheel's flat spot).
3. **The level**: the highest fused ``z`` of each :data:`BLOCK_M` stretch of the line follows
   a Gumbel law where there is no dip; fitted to its :data:`FIT_QUANTILES` (the line's defects
   and assets fill the top of the distribution, not its lower half), it gives the places per km
   that the texture reaches at any ``z``: on the development physics tracks' clean twins the
   fit gives 5.3 at 0.1 places per km, 5.2 counted
   (docs/notes/2026-12-05-welds-from-the-rails-height.md).
4. **Places**: the stretches above the level of ``list_per_km``, less the **sidelobes**: the
   whitened test rings beside a strong dip (a step, a crossing nose, a bridge's end: z of
   50-300), at about 6 m and, by a bridge's stiff deck, 10-27 m, at z 5-7; a stretch whose
   peak has a five times stronger one within 25 m is left out (on the development tracks every
   such stretch lay on the stronger item's feature or defect, and every weld of 0.3 mm or more
   was 40 m or more from a stronger stretch). A place the event layer already has (within its
   tolerance) takes the weld test's ``z`` as ``weld_z``, another one becomes a place of its
   own.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railwatch.recordings.prepare import AXLE_GROUPS
from railwatch.trackmap import fusion
from railwatch.trackmap.folder import ScoreProfile

FloatArray = NDArray[np.float64]

#: The group of the weld layer's own places in the map.
GROUP = "rail height"
#: The stretches whose highest fused ``z`` the level is fitted to (m), and the quantiles fitted.
BLOCK_M = 10.0
FIT_QUANTILES = (0.10, 0.50)
#: The null leaves out this much (m) around each of the event layer's places: a defect or an
#: asset raises the weld test over tens of metres (a bridge's end over a hundred).
KNOWN_M = 30.0
#: A stretch whose peak is under 1/SIDELOBE_RATIO of another's within SIDELOBE_M (m) is that
#: one's sidelobe, not a place (module docstring, step 4).
SIDELOBE_M = 25.0
SIDELOBE_RATIO = 5.0
#: Each pass's z is judged against the spread of its own z within SPREAD_M on either side
#: (median to SPREAD_PERCENTILE, of a value every SPREAD_EVERY_M): where the spread is r times
#: the pass's typical one, z is drawn to the pass's median by r from r = SPREAD_RATIO, by
#: 1 + (r - 1)² / (SPREAD_RATIO - 1) below it (step 1). On the test tracks' passes r is
#: 0.85-1.4 over 90 % of the line (5th-95th percentile): a weld there loses 15 % of its z at
#: most; on the slow track's fast stretches it is 10-15.
SPREAD_M = 40.0
SPREAD_PERCENTILE = 75.0
SPREAD_EVERY_M = 0.25
SPREAD_RATIO = 2.0
#: A pass "saw" a weld place where its own z reached the level of this many places per km.
SEEN_PER_KM = 0.1


@dataclass
class WeldLayer:
    """The fused weld test along the map's grid, and its null."""

    grid: FloatArray  # (G,) map positions, m (the event layer's grid)
    fused: FloatArray  # (2, G) each rail's median z over the passes (NaN: under two passes)
    per_pass: FloatArray  # (P, G) each pass's highest z of its two rails (NaN: not covered)
    passes: tuple[int, ...]  # per_pass's rows: the indices of those passes in the profiles
    covered: NDArray[np.int64]  # (G,) passes with a weld test at each grid point
    mu: float  # the Gumbel law of the highest fused z per BLOCK_M
    beta: float
    channels: tuple[str, str]  # the axle box over each rail on a pass up the map

    @property
    def top(self) -> FloatArray:
        """(G,) the fused z of the stronger rail."""
        with np.errstate(invalid="ignore"):
            return np.fmax(self.fused[0], self.fused[1])

    def false_per_km(self, z: FloatArray | float) -> FloatArray:
        """Places per km at least this strong where the rails have no dip (step 3)."""
        z = np.atleast_1d(np.asarray(z, dtype=float))
        tail = -np.expm1(-np.exp(-(z - self.mu) / self.beta))
        return np.asarray(tail * 1000.0 / BLOCK_M)

    def level(self, false_per_km: float) -> float:
        """The ``z`` that :meth:`false_per_km` places per km reach by chance."""
        tail = false_per_km * BLOCK_M / 1000.0
        return float(self.mu - self.beta * math.log(-math.log1p(-tail)))


def gumbel_fit(block_maxima: FloatArray) -> tuple[float, float]:
    """(μ, β) of the Gumbel law through the :data:`FIT_QUANTILES` of ``block_maxima``."""
    qa, qb = FIT_QUANTILES
    xa, xb = np.quantile(block_maxima, [qa, qb])
    ya, yb = -math.log(-math.log(qa)), -math.log(-math.log(qb))
    beta = max(float(xb - xa) / (yb - ya), 1e-6)
    return float(xb - beta * yb), beta


def deflated(z: FloatArray, x: FloatArray) -> FloatArray:
    """One pass's ``z`` on one rail at its positions ``x`` (evenly spaced, in pass order),
    drawn to the pass's median where the stretch's spread is wider than the pass's typical
    one (:data:`SPREAD_RATIO`; module docstring, step 1). The stretch is the wider-spread of
    the :data:`SPREAD_M` before and the :data:`SPREAD_M` after (a greatest-of CFAR: a point
    just inside a wide stretch is judged by it, not by the quiet track beside it)."""
    out = np.asarray(z, dtype=float).copy()
    ok = np.isfinite(out)
    step = float(np.nanmedian(np.abs(np.diff(np.asarray(x, dtype=float))))) if len(x) > 1 \
        else 0.0
    stride = max(1, int(round(SPREAD_EVERY_M / step))) if step > 0 else 1
    v = out[ok]
    coarse = v[::stride]
    width = int(round(SPREAD_M / (stride * step))) if step > 0 else 0
    if width < 4 or len(coarse) < 2 * width:
        return out
    padded = np.concatenate([coarse[width:0:-1], coarse, coarse[-2:-width - 2:-1]])
    windows = np.lib.stride_tricks.sliding_window_view(padded, width + 1)
    level, top = np.percentile(windows, [50.0, SPREAD_PERCENTILE], axis=1)
    before = slice(0, len(coarse))  # the window ending at each point, and the one starting
    after = slice(width, width + len(coarse))
    spread = np.fmax(top[before] - level[before], top[after] - level[after])
    typical = float(np.median(spread))
    if not typical > 0:
        return out
    spread = np.interp(np.arange(len(v)), np.arange(len(coarse)) * stride, spread)
    ratio = np.maximum(spread / typical, 1.0)
    ramp = np.minimum((ratio - 1.0) / (SPREAD_RATIO - 1.0), 1.0)  # 0 at 1, 1 from SPREAD_RATIO
    middle = float(np.median(v))  # the pass's: a stretch's own median is too noisy a centre
    out[ok] = middle + (v - middle) / (1.0 + (ratio - 1.0) * ramp)
    return out


def weld_layer(profiles: list[ScoreProfile], transforms: list[tuple[float, float]],
               grid: FloatArray, mirrored: list[bool],
               known: Sequence[tuple[float, float]] = ()) -> WeldLayer | None:
    """The fused weld test (module docstring) of the passes whose profiles carry one, laid on
    the map's ``grid`` by each pass's ``transforms`` (``a + b · recorded position``);
    ``mirrored[i]``: pass i's axle boxes swap rails. The null is fitted away from the
    stretches ``known`` (the event layer's places: each with :data:`KNOWN_M` around it). None
    when fewer than two passes carry a weld test."""
    rows = [i for i, pr in enumerate(profiles)
            if pr.weld_z is not None and pr.weld_position is not None]
    with_test = [(profiles[i], transforms[i], mirrored[i]) for i in rows]
    if len(with_test) < fusion.MIN_PASSES or len(grid) < 2:
        return None
    step = float(grid[1] - grid[0])
    lo, n = float(grid[0]), len(grid)
    rails = np.full((2, len(with_test), n), np.nan)
    for i, (pr, (a, b), mirror) in enumerate(with_test):
        x = a + b * np.asarray(pr.weld_position)
        z = np.asarray(pr.weld_z, dtype=float)[:, ::-1] if mirror else \
            np.asarray(pr.weld_z, dtype=float)
        z = np.stack([deflated(z[:, rail], x) for rail in range(2)], axis=1)
        for rail in range(2):
            rails[rail, i] = fusion.grid_profile(x, z[:, rail], lo, n, step)
    covered = np.isfinite(rails).any(axis=0).sum(axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: no pass there
        fused = np.nanmedian(rails, axis=1)
    fused[:, covered < fusion.MIN_PASSES] = np.nan
    per_pass = np.fmax(rails[0], rails[1])
    top = np.fmax(fused[0], fused[1])
    per_block = max(1, int(round(BLOCK_M / step)))
    m = len(top) // per_block * per_block
    away = top.copy()
    for lo_m, hi_m in known:
        away[(grid >= lo_m - KNOWN_M) & (grid <= hi_m + KNOWN_M)] = np.nan
    blocks = away[:m].reshape(-1, per_block)
    full = np.isfinite(blocks).sum(axis=1) >= per_block // 2
    if full.sum() < 20:  # under 200 m of line: no null to fit
        return None
    maxima = np.nanmax(blocks[full], axis=1)
    mu, beta = gumbel_fit(maxima)
    axle = [c for c, g in zip(with_test[0][0].channels, with_test[0][0].groups, strict=True)
            if g.lower() in AXLE_GROUPS]
    channels = (axle[0], axle[1]) if len(axle) == 2 else ("rail 1", "rail 2")
    return WeldLayer(grid=grid, fused=fused, per_pass=per_pass, passes=tuple(rows),
                     covered=covered, mu=mu, beta=beta, channels=channels)


@dataclass(frozen=True)
class WeldPlace:
    """A stretch where the fused weld test clears the level (module docstring, step 4)."""

    position_m: float  # where the stronger rail's fused z peaks
    start_m: float
    end_m: float
    z: float  # its fused z there
    false_per_km: float
    seen_by: tuple[int, ...]  # the passes (profile indices) whose own z there reaches the
    # reporting level
    passes_covered: int
    channel: str  # the axle box over the rail with the dip, on a pass up the map


def weld_places(layer: WeldLayer, list_per_km: float, seen_per_km: float,
                tolerance_m: float) -> list[WeldPlace]:
    """The stretches where the fused weld test reaches ``list_per_km`` places per km by
    chance, stretches closer than ``tolerance_m`` merged; a pass "saw" a place where its own
    z reached the level of ``seen_per_km``."""
    top = layer.top
    step = float(layer.grid[1] - layer.grid[0])
    gap = max(1, int(round(tolerance_m / step)))
    seen_level = layer.level(seen_per_km)
    runs = fusion.runs_above(np.nan_to_num(top, nan=-np.inf), layer.level(list_per_km), gap)
    peaks = np.array([int(run[np.argmax(top[run])]) for run in runs], dtype=np.int64)
    out = []
    for run, peak in zip(runs, peaks, strict=True):
        near = np.abs(layer.grid[peaks] - layer.grid[peak]) <= SIDELOBE_M
        if np.any(top[peaks[near]] >= SIDELOBE_RATIO * top[peak]):
            continue  # the whitened test's sidelobe of a much stronger dip (module docstring)
        lo, hi = int(run[0]), int(run[-1]) + 1
        own = np.nanmax(np.where(np.isnan(layer.per_pass[:, lo:hi]), -np.inf,
                                 layer.per_pass[:, lo:hi]), axis=1)
        covering = np.isfinite(layer.per_pass[:, peak])
        rail = int(np.nan_to_num(layer.fused[1, peak], nan=-np.inf)
                   > np.nan_to_num(layer.fused[0, peak], nan=-np.inf))
        out.append(WeldPlace(
            position_m=float(layer.grid[peak]), start_m=float(layer.grid[lo]),
            end_m=float(layer.grid[hi - 1]), z=float(top[peak]),
            false_per_km=float(layer.false_per_km(top[peak])[0]),
            seen_by=tuple(layer.passes[j] for j in np.flatnonzero((own >= seen_level)
                                                                   & covering)),
            passes_covered=int(covering.sum()), channel=layer.channels[rail]))
    return sorted(out, key=lambda p: -p.z)
