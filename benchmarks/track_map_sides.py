"""The sides of the vehicle: what the fused map sums over the passes (`track-map --sides`), on
eight development tracks.

Eight development tracks of each kind (seeds 12-19; the test track, seed 11, is not used):
10 km, 40 defects, stage-5-like and stage-8-like nuisance with loud stretches; the matched
filter trained on passes 1-2 (on stage 8 also with `--wheel-comb`, the turn estimated: the
scans of `benchmarks/track_map_wheel.py`), passes 3-7 and 8-12 make two 5-pass maps per track
(16 per cell), passes 3-12 one 10-pass map (8 per cell). Passes placed by odometry alone
(`generate-run --passes` defaults) and by the GNSS-aided odometry. Recall within ±2 m / false
places per km of `track-map`'s default reporting rule (0.1 per km by chance), the mean over the
maps (the lowest recall in brackets). A defect is under one rail, and a pass feels it on the
channel of that side of the vehicle; in the synthesiser the sides swap rails when the vehicle
runs the other way (a vehicle turned at the line's ends). The fused map sums each kind of
evidence over the passes; the kinds by each rule of `--sides`:

1. **group**: each sensor group's highest channel (the map's rule before this benchmark: the
   group does not depend on the direction, the side does); a defect's channel shares the max
   with the other side's noise, which about doubles the share of a pass's values that reach
   the defect's;
2. **keep**: each channel as recorded (right for a push-pull vehicle, whose sides stay on their
   rails; here half of the passes put a defect on the other channel);
3. **swap**: each channel, a pass down the map with each sensor group's channels in reverse
   order (right for a turned vehicle: the synthesiser's world);
4. **auto** (`track-map`'s default): keep or swap, the one with the more evidence summed over
   its places stronger than chance gives 0.1 times per km; the last column says on how many
   of the placement's 24 maps (16 from 5 passes, 8 from 10) it chose swap.

The rows "push-pull" are tracks made like the others with `generate-run --push-pull` (the
vehicle runs back without turning, so a defect is felt on the same channel both ways: `keep`
is right there, `swap` wrong): the same seeds, the matched filter trained and scanned on them
here. Each map's result is kept in `WORK/track-map-sides.json`: a second run measures only
what is missing.

Run after `benchmarks/track_map_frame.py` and `benchmarks/track_map_wheel.py` (which make and
scan the tracks): `make bench-track-map-sides`, about 50 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from benchmarks import track_map as bench

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ('track_map_frame', 'track_map_wheel')
PAGE = "docs/results/track-map/track-map-sides.md"
MINUTES = 50

ROLES = bench.DEV_ROLES
SUBSETS = {"5": (slice(0, 5), slice(5, 10)), "10": (slice(0, 10),)}
PLACEMENTS = {"odometry alone": None, "GNSS-aided": bench.ODOMETRIES["GNSS-aided"]}
RULES = ("group", "keep", "swap", "auto")
#: (nuisance, detector as named on the page, whether the passes are combed first)
ROWS = (("stage 5", "matched-filter", False), ("stage 8", "matched-filter", False),
        ("stage 8", "matched-filter-wheel", True),
        ("stage 5 push-pull", "matched-filter", False),
        ("stage 8 push-pull", "matched-filter", False))
PUSH_PULL = {f"{kind} push-pull": [*bench.KINDS[kind], "--push-pull"] for kind in bench.KINDS}


def scan_of(work: Path, kind: str, role: str, combed: bool) -> tuple[Path, Path]:
    """The track's folder and its matched filter's scan at the model's threshold (of the
    combed passes: made by ``benchmarks/track_map_wheel.py``)."""
    folder = bench.track(work, kind, role)
    source = folder.with_name(folder.name + "-wheel-estimated") if combed else folder
    if not source.is_dir():
        raise SystemExit(f"{source} is missing: run python -m benchmarks track_map_wheel first")
    low = min(bench.FACTORS)
    return folder, bench.above(bench.scanned(source, "matched-filter", low), 1.0, low)


def measure(work: Path, kind: str, detector: str, role: str, combed: bool,
            keys: dict[tuple[str, str, str, str], str], done: dict[str, list]) -> None:  # type: ignore[type-arg]
    """Every map of one track and row: ``done[key]`` = [recall, false per km, rule used]."""
    from railwatch import trackmap as tm
    from railwatch.evaluation import maps as em

    folder, base = scan_of(work, kind, role, combed)
    truth = em.read_truth(folder / "track.defects.csv")
    for placed, odometry in PLACEMENTS.items():
        events = base if odometry is None else bench.with_odometry(
            base, folder, kind, role, odometry)
        passes = tm.read_scan(events)
        for count, subsets in SUBSETS.items():
            for subset in subsets:
                use = passes[subset]
                lo, hi = tm.covered_range(use)
                covered = em.on_stretch(truth, lo, hi)
                for rule in RULES:
                    locations, fused = tm.fused_map(use, sides=rule)
                    s = em.score_locations(tm.reported_fused(locations), covered, hi - lo)
                    done[keys[(placed, count, str(subset), rule)]] = [
                        s["recall"], s["false_per_km"], fused.sides]


def main() -> None:
    np.seterr(all="ignore")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("runs/bench-track-map"))
    parser.add_argument("--out", type=Path, default=Path(PAGE))
    args = parser.parse_args()
    from railwatch.report.pages import write_markdown

    bench.SEEDS.update(ROLES)
    bench.KINDS.update(PUSH_PULL)
    args.work.mkdir(parents=True, exist_ok=True)
    store = args.work / "track-map-sides.json"
    done = json.loads(store.read_text()) if store.exists() else {}
    cells: dict[tuple[str, str, str, str, str], list[tuple[float, float]]] = {}
    chose: dict[tuple[str, str, str], list[str]] = {}
    for kind, detector, combed in ROWS:
        for role in ROLES:
            keys = {(placed, count, str(subset), rule): "|".join(
                (kind, detector, role, placed, f"{subset.start}-{subset.stop}", rule))
                for placed in PLACEMENTS for count, subsets in SUBSETS.items()
                for subset in subsets for rule in RULES}
            if not all(key in done for key in keys.values()):
                measure(args.work, kind, detector, role, combed, keys, done)
                store.write_text(json.dumps(done, indent=0))
            for (placed, count, _, rule), key in keys.items():
                recall, false, sides = done[key]
                cells.setdefault((kind, detector, placed, count, rule), []).append(
                    (recall, false))
                if rule == "auto":
                    chose.setdefault((kind, detector, placed), []).append(sides)
            print(kind, detector, role, "done", flush=True)
    rows = ["| nuisance | detector | placed by | passes | " + " | ".join(RULES)
            + " | auto chose swap |", "|---|---|---|---|" + "---|" * (len(RULES) + 1)]
    for kind, detector, _ in ROWS:
        for placed in PLACEMENTS:
            for count in SUBSETS:
                text = []
                for rule in RULES:
                    v = np.array(cells[(kind, detector, placed, count, rule)])
                    text.append(f"{v[:, 0].mean():.1%} / {v[:, 1].mean():.2f} "
                                f"({v[:, 0].min():.0%})")
                picks = chose[(kind, detector, placed)]
                rows.append(f"| {kind} | {detector} | {placed} | {count} | " + " | ".join(text)
                            + f" | {picks.count('swap')} of {len(picks)} |")
    command, items = bench.page_head(__name__, __doc__)
    push_pull = " ".join(__doc__.split("\n\n")[3].split())
    lines = ["# The sides of the vehicle: what the fused map sums over the passes", "",
             command, "", *items, "", push_pull, "", *rows]
    print(write_markdown(args.out, lines))


if __name__ == "__main__":
    main()
