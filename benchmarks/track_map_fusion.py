"""What each step of the fused track map adds: the map's rules switched back one at a time, on
development tracks only.

The matched filter's scans of `benchmarks/track_map.py`'s development tracks (seed 12) and of a
second development track of each kind made the same way (seed 13; stage-5-like and
stage-8-like nuisance with loud stretches; passes 1-2 train, 3-12 are mapped), passes placed
by odometry alone, by the GNSS-aided odometry and at their true positions. Recall within ±2 m /
false places per km of `track-map`'s default rule (0.1 false places per km by chance), from
5 passes (passes 3-7 and 8-12: two maps per track) and from 10. The rules, cumulatively:

1. **first rules**: each pass ranked within its ±100 m neighbourhood (outside ±10 m), Fisher's
   combination, the alignment by events alone (the repairs of the alignment itself, pairs
   compared with pairs, the chance gate, the check of the moves by the profiles and the
   frame from the passes' starts, are in every row, as are the two passes a place needs,
   its position from every covering pass and `scan`'s central score profile);
2. **+ ranked against the whole pass** after the local scaling by the neighbourhood's median
   and 90th percentile;
3. **+ Stouffer's combination** instead of Fisher's;
4. **+ the profile refinement** of the alignment (the map as it is).

Run after `benchmarks/track_map.py` (which makes the seed-12 tracks and scans; the seed-13
tracks are made here): `make bench-track-map-fusion`, about 15 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.special import gammaincc

from benchmarks import track_map as bench

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ('track_map',)
PAGE = "docs/results/track-map/track-map-fusion.md"
MINUTES = 15

SEEDS = {"dev": 12, "dev2": 13}
SUBSETS = {"5 (3-7)": slice(0, 5), "5 (8-12)": slice(5, 10), "10": slice(0, 10)}
PLACEMENTS = {"odometry alone": None, "GNSS-aided": bench.ODOMETRIES["GNSS-aided"],
              "true positions": (0.0, 0.0, 0.0)}
STEPS = ("first rules", "+ ranked against the pass", "+ Stouffer", "+ profile refinement")


def neighbourhood_rank(profile: NDArray[np.float64], half: int,
                       guard: int = 40) -> NDArray[np.float64]:
    """The first calibration: the share of the pass's grid values within ``half`` points on
    either side, outside ``guard`` points, that reach the value here (1 + ties and above over
    1 + neighbours)."""
    n = len(profile)
    pad = np.concatenate([np.full(half, np.nan), profile, np.full(half, np.nan)])
    offsets = np.r_[np.arange(-half, -guard), np.arange(guard + 1, half + 1)]
    out = np.full(n, np.nan)
    for start in range(0, n, 2048):
        centre = np.arange(start, min(start + 2048, n))
        here = profile[centre]
        around = pad[centre[:, None] + half + offsets[None, :]]
        valid = np.isfinite(around)
        count = valid.sum(axis=1)
        p = (1 + ((around >= here[:, None]) & valid).sum(axis=1)) / (1 + count)
        p[~np.isfinite(here) | (count == 0)] = np.nan
        out[centre] = p
    return out


def fisher(calibrated: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The first combination: −log10 of the Gamma(k, 1) tail of Σ −ln p."""
    ok = np.isfinite(calibrated)
    k = ok.sum(axis=0)
    total = np.where(ok, calibrated, 0.0).sum(axis=0)
    tail = np.where(k > 0, gammaincc(np.maximum(k, 1), total), 1.0)
    return -np.log10(np.maximum(tail, 1e-300)), k


@contextmanager
def rules(step: int) -> Iterator[None]:
    """The map's rules up to ``step`` (an index into STEPS), the later ones switched back, in
    :mod:`railwatch.trackmap.fusion`, whose functions the map calls through the module (until
    2026-12-07 the refinement was switched as ``trackmap.refine_by_profiles``, a name the map
    no longer called after the re-layout of 2026-12-03: the last two columns were equal)."""
    from railwatch.trackmap import fusion

    saved = fusion.calibrate, fusion.combine, fusion.profile_shifts
    if step < 1:
        fusion.calibrate = neighbourhood_rank  # type: ignore[assignment]
    if step < 2:
        fusion.combine = fisher
    if step < 3:  # no shift from the profiles: the events' alignment in its frame
        fusion.profile_shifts = (  # type: ignore[assignment]
            lambda xs, scores, *_, **__: [(0.0, 0.0)] * len(xs))
    try:
        yield
    finally:
        fusion.calibrate, fusion.combine, fusion.profile_shifts = saved


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("runs/bench-track-map"))
    parser.add_argument("--out", type=Path, default=Path(PAGE))
    args = parser.parse_args()
    from railwatch import trackmap as tm
    from railwatch.evaluation import maps as em
    from railwatch.report.pages import write_markdown

    bench.SEEDS.update(SEEDS)
    rows = ["| nuisance | placed by | passes | " + " | ".join(STEPS) + " |",
            "|---|---|---|" + "---|" * len(STEPS)]
    totals = np.zeros((len(STEPS), 2))
    count = 0
    for kind in bench.KINDS:
        folders = {role: bench.track(args.work, kind, role) for role in SEEDS}
        for placed, odometry in PLACEMENTS.items():
            cells: dict[str, list[list[dict[str, float]]]] = {s: [] for s in SUBSETS}
            for role, folder in folders.items():
                events = bench.above(bench.scanned(folder, "matched-filter", min(bench.FACTORS)),
                                     1.0, min(bench.FACTORS))
                if odometry is not None:
                    events = bench.with_odometry(events, folder, kind, role, odometry,
                                                 "-true" if odometry == (0.0, 0.0, 0.0)
                                                 else "-gnss")
                passes = tm.read_scan(events)
                truth = em.read_truth(folder / "track.defects.csv")
                for label, subset in SUBSETS.items():
                    use = passes[subset]
                    lo, hi = tm.covered_range(use)
                    covered = em.on_stretch(truth, lo, hi)
                    scores = []
                    for step in range(len(STEPS)):
                        with rules(step):
                            shown = tm.reported_fused(tm.fused_map(use)[0])
                        scores.append(em.score_locations(shown, covered, hi - lo))
                    cells[label].append(scores)
            for label, per_track in cells.items():
                text = []
                for step in range(len(STEPS)):
                    recall = np.mean([t[step]["recall"] for t in per_track])
                    false = np.mean([t[step]["false_per_km"] for t in per_track])
                    text.append(f"{recall:.0%} / {false:.2f}")
                    if label != "10":
                        totals[step] += (recall, false)
                count += label != "10"
                rows.append(f"| {kind} | {placed} | {label} | " + " | ".join(text) + " |")
                print(rows[-1], flush=True)
    mean = totals / max(count, 1)
    command, items = bench.page_head(__name__, __doc__)
    lines = [
        "# What each step of the fused track map adds",
        "",
        command,
        "",
        *items,
        "",
        "Each cell: recall / false places per km, the mean of the two development tracks "
        "(seeds 12 and 13).",
        "",
        *rows,
        "",
        "Mean over the 5-pass maps (both tracks, both sets of passes, every nuisance and "
        "placement): " + "; ".join(f"{s}: {m[0]:.0%} / {m[1]:.2f}"
                                   for s, m in zip(STEPS, mean, strict=True)),
    ]
    print(write_markdown(args.out, lines))


if __name__ == "__main__":
    main()
