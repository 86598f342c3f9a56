"""A place's strength over dated passes, and whether it grows faster than chance.

Per place and pass that covered it, the **strength** is the pass's highest value within the
place's stretch (± ``reach_m``), and the **speed** the pass ran there (from the scan's sample
times and positions). The value is the axle boxes' **low band**, |acceleration| below
:data:`BAND_HZ`, where the scan kept it (a recording at field rate, :func:`low_band`), and the
detector's score otherwise. A squat that deepens and lengthens pushes the wheelset down
further on the track (P2, 30-90 Hz) while its sharp impact above a few hundred Hz hardly
grows: on the development lines the defect's own response below 200 Hz grew 1.77 times where
the squats deepened 2.34 times, above 200 Hz 1.24 times; on their maps the detector's score
flagged 70 % of the grown squats, the low band 90 %
(docs/notes/2026-12-05-growth-in-the-low-band.md). Strengths are compared like with like:

1. **Per pass**: ``log`` strength; a detector's score less the pass's own offset, the median
   over the places of how far that pass sits above each place's median (a pass whose noise
   or gain is higher raises every place alike). The low band is an acceleration in the
   sensor's units, the same gain on every pass of one vehicle: it keeps its level (with the
   offset, half the squats growing on a line raise the later passes' offsets, and the
   development lines flagged 80 % of the grown squats instead of 90 %);
2. **Per place**: least squares of what is left on the pass's date (days) and on ``log``
   speed (an impact changes with speed, and how much depends on the place: on the development
   line the slopes ran from −2.6 for the smallest squats to +2.9 for welds and corrugation,
   so one slope for the line took speed for growth). ``growth`` = ``exp(slope · span)``, the
   fitted strength at the last pass over the first's, ``growth_low``/``growth_high`` its 95 %
   interval, and the place is **growing** when the date's slope is positive with a one-sided
   ``p`` (Student's t) below :data:`GROWING_P` (``trend_p``): a stable place is flagged that
   often.

A place needs :data:`MIN_PASSES` dated passes over it for a trend, one more with its speeds.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.signal import butter, sosfiltfilt
from scipy.stats import t as student_t

from railwatch.atomic import atomic_csv
from railwatch.trackmap.folder import Location, PassEvents, started_time
from railwatch.trackmap.fusion import Fused

#: A place's strength is its low band: |acceleration| below this (Hz), above P2 (the wheelset
#: bouncing on the track, 30-90 Hz) with margin, below the impact's sharp part.
BAND_HZ = 200.0
#: ... kept where the recording's rate is at least this many times the band (a recording at
#: the benchmark's 100 Hz keeps none: its trends measure the detector's score).
BAND_RATE = 4.0
#: A place is growing when a stable place gives a slope this steep this rarely (one-sided): half
#: the 5 % of stable places a work list may flag, the rest a margin for residuals that are not
#: quite Student's (2.4-3.6 % of 1,600 synthetic stable places, tests/trackmap/test_trends.py).
#: On the development lines (physics lines 500, 504-506: 20 squats grown by half or more, 77
#: stable defects), on the detector's score, 0.01 flagged 45 % of the grown and 2.6 % of the
#: stable, 0.025 60 % and 3.9 %, 0.05 75 % and 3.9 % (docs/maintenance.md); on the low band
#: 0.025 flags 90 % and none.
GROWING_P = 0.025
#: Dated passes a place needs for a trend (one more when its speeds are known).
MIN_PASSES = 4
#: The strength is floored here (a score at or under 0 has no logarithm).
FLOOR = 1e-3


@dataclass(frozen=True)
class Trend:
    """A place's trend over the dated passes (module docstring); NaN where it has none."""

    growth: float
    growth_low: float
    growth_high: float
    trend_p: float
    growing: bool
    passes: int


NO_TREND = Trend(math.nan, math.nan, math.nan, math.nan, False, 0)


def low_band(data: NDArray[np.floating], fs: float) -> NDArray[np.float32] | None:
    """Each sample's |acceleration| below :data:`BAND_HZ` per channel ((n, C) as ``data``, a
    zero-phase Butterworth of order 4; NaN where the sample was); None where ``fs`` is below
    :data:`BAND_RATE` times the band."""
    if fs < BAND_RATE * BAND_HZ or len(data) < 30:
        return None
    x = np.asarray(data, dtype=np.float64)
    bad = ~np.isfinite(x)
    sos = butter(4, BAND_HZ, fs=fs, output="sos")
    out = np.abs(sosfiltfilt(sos, np.where(bad, 0.0, x), axis=0))
    out[bad] = np.nan
    return out.astype(np.float32)


def days(started: list[str | None]) -> NDArray[np.float64]:
    """Days since the first dated pass (NaN: undated)."""
    stamps = [started_time(s) if s else None for s in started]
    known = [s for s in stamps if s is not None]
    if not known:
        return np.full(len(stamps), np.nan)
    first = min(known)
    return np.array([(s - first).total_seconds() / 86400.0 if s is not None else np.nan
                     for s in stamps])


def strengths(stretches: NDArray[np.float64], xs: list[NDArray[np.float64]],
              scores: list[NDArray[np.float64]],
              times: list[NDArray[np.float64] | None] | None = None,
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(stretches, passes): each pass's highest score on each stretch of the map ((n, 2) from
    and to, m), and the speed it ran there (m/s, from the samples' ``times``); NaN where the
    pass did not cover the whole stretch (or has no times)."""
    stretches = np.asarray(stretches, dtype=float).reshape(-1, 2)
    s = np.full((len(stretches), len(xs)), np.nan)
    v = np.full_like(s, np.nan)
    for j, (x, sc) in enumerate(zip(xs, scores, strict=True)):
        ok = np.isfinite(x) & np.isfinite(sc)
        order = np.argsort(x[ok])
        xo, so = x[ok][order], sc[ok][order]
        t = times[j] if times is not None else None
        to = np.asarray(t)[ok][order] if t is not None else None
        if not len(xo):
            continue
        for i, (lo_m, hi_m) in enumerate(stretches):
            if not (xo[0] <= lo_m and xo[-1] >= hi_m):
                continue
            lo = np.searchsorted(xo, lo_m)
            hi = np.searchsorted(xo, hi_m, side="right")
            if hi <= lo:
                continue
            s[i, j] = float(so[lo:hi].max())
            if to is not None and hi - lo > 1:
                span_t = float(to[lo:hi].max() - to[lo:hi].min())
                if span_t > 0:
                    v[i, j] = float(xo[hi - 1] - xo[lo]) / span_t
    return s, v


def measured(fused: Fused) -> list[NDArray[np.float64]]:
    """What a strength is read from on each pass: the low band where every pass has it, else
    the detector's score (module docstring)."""
    return fused.pass_band if fused.pass_band else fused.pass_score


def unit(fused: Fused) -> str:
    """What :func:`measured` reads, in words (a plot's axis)."""
    return f"low band (|acceleration| below {BAND_HZ:.0f} Hz)" if fused.pass_band else "score"


def adjusted(strength: NDArray[np.float64], per_pass: bool = True) -> NDArray[np.float64]:
    """Log strengths less each pass's own offset (module docstring, step 1; ``per_pass``
    False: the log strengths as they are, for the low band)."""
    y = np.log(np.maximum(strength, FLOOR))
    if not per_pass:
        return y
    with warnings.catch_warnings():  # rows or columns without a value
        warnings.simplefilter("ignore", RuntimeWarning)
        centred = y - np.nanmedian(y, axis=1, keepdims=True)
        offset = np.nan_to_num(np.nanmedian(centred, axis=0))
    return y - offset[None, :]


def trend(y: NDArray[np.float64], t: NDArray[np.float64],
          speed: NDArray[np.float64] | None = None) -> Trend:
    """One place's trend from its adjusted log strengths ``y`` at days ``t`` (and the speeds
    the passes ran there: taken out where every pass has one): least squares of ``y`` on the
    date and log speed, the date's slope tested one-sided with Student's t."""
    ok = np.isfinite(y) & np.isfinite(t)
    lv = np.log(speed) if speed is not None else np.full(len(y), np.nan)
    with_speed = bool(np.isfinite(lv[ok]).all())
    need = MIN_PASSES + (1 if with_speed else 0)
    if ok.sum() < need or np.ptp(t[ok]) <= 0:
        return NO_TREND
    cols = [np.ones(ok.sum()), t[ok] - t[ok].mean()]
    if with_speed and np.ptp(lv[ok]) > 0:
        cols.append(lv[ok] - lv[ok].mean())
    X = np.column_stack(cols)
    coef, _, rank, _ = np.linalg.lstsq(X, y[ok], rcond=None)
    dof = int(ok.sum()) - X.shape[1]
    if rank < X.shape[1] or dof < 1:
        return NO_TREND
    resid = y[ok] - X @ coef
    cov = np.linalg.inv(X.T @ X) * float(resid @ resid) / dof
    se = math.sqrt(max(float(cov[1, 1]), 1e-300))
    slope = float(coef[1])
    p = float(student_t.sf(slope / se, dof))
    half = float(student_t.ppf(0.975, dof)) * se
    span = float(np.ptp(t[ok]))
    return Trend(float(np.exp(slope * span)), float(np.exp((slope - half) * span)),
                 float(np.exp((slope + half) * span)), p, bool(p < GROWING_P and slope > 0),
                 int(ok.sum()))


#: Columns of the per-pass table (``MAP.passes.csv``): each place's strength on each pass.
PASS_FIELDS = ("rank", "position_m", "pass", "started", "days", "strength", "speed_ms",
               "adjusted")


@dataclass
class Dated:
    """A map's places with their trends, and the per-pass rows behind them."""

    places: list[Location]
    rows: list[dict[str, object]]


def with_trends(places: list[Location], passes: list[PassEvents], fused: Fused,
                reach_m: float) -> Dated:
    """The places of a fused map with their trends over the dated ``passes`` (in the order
    the map fused them), and each place's strength per pass."""
    centres = np.array([p.position_m for p in places], dtype=float)
    started = [p.started for p in passes]
    times = [p.profile.time_s if p.profile is not None else None for p in passes]
    t = days(started)
    if np.isfinite(t).sum() < MIN_PASSES or not len(places):
        return Dated(places, [])
    s, v = strengths(np.stack([centres - reach_m, centres + reach_m], axis=1), fused.pass_x,
                     measured(fused), times)
    y = adjusted(s, per_pass=not fused.pass_band)
    out, rows = [], []
    for i, place in enumerate(places):
        tr = trend(y[i], t, v[i])
        out.append(replace(place, growth=tr.growth, growth_low=tr.growth_low,
                           growth_high=tr.growth_high, trend_p=tr.trend_p,
                           growing="" if tr.passes == 0 else "yes" if tr.growing else "no"))
        for j, p in enumerate(passes):
            if np.isfinite(s[i, j]):
                rows.append({"rank": place.rank, "position_m": f"{place.position_m:.2f}",
                             "pass": p.name, "started": p.started or "",
                             "days": "" if not np.isfinite(t[j]) else f"{t[j]:.3f}",
                             "strength": f"{s[i, j]:.4f}",
                             "speed_ms": "" if not np.isfinite(v[i, j]) else f"{v[i, j]:.2f}",
                             "adjusted": f"{y[i, j]:.4f}"})
    return Dated(out, rows)


def history(places: list[Location], passes: list[PassEvents], fused: Fused, reach_m: float
            ) -> list[dict[str, object]]:
    """Each place's strength on each pass that covered it (as :func:`with_trends` measures
    it, dated or not): rank, pass, started (ISO 8601 or None), order (the pass's place in
    ``passes``, from 1), strength."""
    if not places:
        return []
    centres = np.array([p.position_m for p in places], dtype=float)
    s, _ = strengths(np.stack([centres - reach_m, centres + reach_m], axis=1), fused.pass_x,
                     measured(fused))
    return [{"rank": place.rank, "pass": p.name, "started": p.started, "order": j + 1,
             "strength": float(s[i, j])}
            for i, place in enumerate(places) for j, p in enumerate(passes)
            if np.isfinite(s[i, j])]


def write_passes(path: str | os.PathLike[str], dated: Dated) -> Path:
    """``MAP.passes.csv``: each place's strength per pass (:data:`PASS_FIELDS`)."""
    return atomic_csv(path, PASS_FIELDS, dated.rows)
