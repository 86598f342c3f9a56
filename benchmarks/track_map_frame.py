"""Where the fused map's positions come from: the map's frame and the check of the alignment's
moves, switched off one at a time, on eight development tracks.

Eight development tracks of each kind (seeds 12-19; the test track, seed 11, is not used):
10 km, 40 defects, stage-5-like and stage-8-like nuisance with loud stretches, passes 1-2
train the matched filter, passes 3-7 and 8-12 make two 5-pass maps per track (16 maps per
cell). Passes placed by odometry alone (`generate-run --passes` defaults: offset 1 m, drift
0.05 %, walk 0.3 m per √km), by the GNSS-aided odometry and at their true positions. Recall
within ±2 m / false places per km of `track-map`'s default rule, the mean over the 16 maps
(the lowest recall of the 16 in brackets). The variants:

1. **median frame, no check**: the map's frame is the median of every pass's odometry at each
   end of the aligned stretch, and the events' alignment is taken as it is (the map before
   this benchmark);
2. **+ check of the moves**: a pass that the events moved goes back where it was recorded
   when its score profile lies on the other passes' better there (`fusion.keeps_move`);
3. **frame from the starts, no check**: each end of the stretch takes the median of the passes
   that started at that end (an odometer errs little near where it was set);
4. **both** (the map as it is).

Run after `benchmarks/track_map.py` (which makes the seed-12 tracks): `make
bench-track-map-frame`, about 30 minutes on 2 cores (10 with `--placements "odometry alone"`),
and half a minute more for each track of seeds 13-19 not yet made and scanned (made here,
once).
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from benchmarks import track_map as bench

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ('track_map',)
PAGE = "docs/results/track-map/track-map-frame.md"
MINUTES = 30

ROLES = bench.DEV_ROLES
SUBSETS = {"3-7": slice(0, 5), "8-12": slice(5, 10)}
PLACEMENTS = {"odometry alone": None, "GNSS-aided": bench.ODOMETRIES["GNSS-aided"],
              "true positions": (0.0, 0.0, 0.0)}
VARIANTS = ("median frame, no check", "+ check of the moves", "frame from the starts, no check",
            "both (the map)")


@contextmanager
def variant(index: int, passes: list) -> Iterator[None]:  # type: ignore[type-arg]
    """The map's rules of ``VARIANTS[index]`` for ``passes`` (their starts hidden for the
    median frame). The switch is made in :mod:`railwatch.trackmap.fusion`, whose functions the
    map calls through the module (a name bound by ``from ... import`` elsewhere would not see
    it: until 2026-12-07 this switched ``trackmap.verify_moves``, which the map no longer
    called after the track map's re-layout of 2026-12-03)."""
    from railwatch.trackmap import fusion

    saved_keeps, saved_starts = fusion.keeps_move, [p.start for p in passes]
    if index in (0, 2):  # every move the events made is kept: no check
        fusion.keeps_move = lambda xs, scores, recorded, **_: [True] * len(xs)  # type: ignore[assignment]
    if index in (0, 1):
        for p in passes:
            p.start = None
    try:
        yield
    finally:
        fusion.keeps_move = saved_keeps  # type: ignore[assignment]
        for p, s in zip(passes, saved_starts, strict=True):
            p.start = s


def main() -> None:
    np.seterr(all="ignore")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("runs/bench-track-map"))
    parser.add_argument("--out", type=Path, default=Path(PAGE))
    parser.add_argument("--placements", default=",".join(PLACEMENTS),
                        help="comma-separated: which of the placements to measure")
    args = parser.parse_args()
    placements = {k: v for k, v in PLACEMENTS.items() if k in args.placements.split(",")}
    from railwatch import trackmap as tm
    from railwatch.evaluation import maps as em
    from railwatch.report.pages import write_markdown

    bench.SEEDS.update(ROLES)
    low = min(bench.FACTORS)
    cells: dict[tuple[str, str, int], list[tuple[float, float]]] = {}
    for kind in bench.KINDS:
        for role in ROLES:
            folder = bench.track(args.work, kind, role)
            base = bench.above(bench.scanned(folder, "matched-filter", low), 1.0, low)
            truth = em.read_truth(folder / "track.defects.csv")
            for placed, odometry in placements.items():
                events = base if odometry is None else bench.with_odometry(
                    base, folder, kind, role, odometry,
                    "-true" if odometry == (0.0, 0.0, 0.0) else "-gnss")
                passes = tm.read_scan(events)
                for subset in SUBSETS.values():
                    use = passes[subset]
                    lo, hi = tm.covered_range(use)
                    covered = em.on_stretch(truth, lo, hi)
                    for index in range(len(VARIANTS)):
                        with variant(index, use):
                            shown = tm.reported_fused(tm.fused_map(use)[0])
                        s = em.score_locations(shown, covered, hi - lo)
                        cells.setdefault((kind, placed, index), []).append(
                            (s["recall"], s["false_per_km"]))
            print(kind, role, "done", flush=True)
    rows = ["| nuisance | placed by | " + " | ".join(VARIANTS) + " |",
            "|---|---|" + "---|" * len(VARIANTS)]
    for kind in bench.KINDS:
        for placed in placements:
            text = []
            for index in range(len(VARIANTS)):
                v = np.array(cells[(kind, placed, index)])
                text.append(f"{v[:, 0].mean():.1%} / {v[:, 1].mean():.2f} "
                            f"({v[:, 0].min():.0%})")
            rows.append(f"| {kind} | {placed} | " + " | ".join(text) + " |")
    command, items = bench.page_head(__name__, __doc__)
    lines = ["# The fused map's frame and the check of the alignment's moves", "", command, "",
             *items, "", *rows]
    print(write_markdown(args.out, lines))


if __name__ == "__main__":
    main()
