"""Trends over dated passes on physics lines whose squats grow: growing places flagged, stable
ones not.

Physics lines of 5 km (`railwatch simulate --passes 12 --start 2026-01-05T06:00Z --every-days 7
--growing 0.5`: half of the squats deepen linearly in time to 1.2-3.0 times their first depth
at the last pass; every default otherwise), the README's workflow (the matched filter trained
on passes 1-2 with defaults, `scan` of passes 3-12, ten weeks), `track-map` with the line's
register (`--assets track.assets.csv`). The trend's rule was developed on line 500 (the
per-place speed slope: docs/maintenance.md); lines 501-503 are test lines, nothing chosen on
them. A defect is on the map when a reported place lies within 5 m of it (odometry alone).
Measured:

1. **Growing**: of the squats on the map that grew by half or more (`growth` >= 1.5 in
   `track.defects.csv`), the share flagged `growing`; and of those that grew less (1.2-1.5);
2. **Stable**: of the defects on the map that did not grow, the share flagged; and of every
   reported place not on a growing squat (defects, features, anything), the share flagged;
3. **Growth**: the median of the map's `growth` (the fitted strength ratio, last pass over
   first) over the flagged squats, beside the median of their true depth ratio;
4. **Oracle**: the same test on what each squat does to the axle box, per pass the peak
   |pass − clean twin| over its rail within 50 ms of the crossing (every squat the passes
   crossed, on the map or not): what the data allow a trend to see.

Run: `make bench-track-map-trends` (about 20 minutes on 2 cores; the lines are kept in
`--work` and reused).
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import railwatch, read_csv
from benchmarks.track_map import page_head

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/track-map/track-map-trends.md"
MINUTES = 20

DEV, TEST = 500, (501, 502, 503)
PASSES, TRAIN = 12, 2
SIMULATE = ("--passes", str(PASSES), "--start", "2026-01-05T06:00Z", "--every-days", "7",
            "--growing", "0.5")
TOLERANCE_M = 5.0
REPORT_PER_KM = 0.1



def mapped(work: Path, seed: int) -> Path:
    """Simulate, train, scan and map one line (each step kept); the map's CSV."""
    folder = work / f"line{seed}"
    if not (folder / "track.defects.csv").exists():
        started = time.perf_counter()
        railwatch("simulate", "--out", str(folder), "--seed", str(seed), *SIMULATE)
        print(f"simulated line {seed}: {time.perf_counter() - started:.0f} s", file=sys.stderr)
    if not (folder / "model" / "recording.json").exists():
        railwatch("train", "--detector", "matched-filter", "--recordings",
                  *[str(folder / f"pass{i + 1:02d}.parquet") for i in range(TRAIN)],
                  "--layout", str(folder / "layout.toml"), "--out", str(folder / "model"))
    railwatch("scan", "--model", str(folder / "model"), "--recordings",
              *[str(folder / f"pass{i + 1:02d}.parquet") for i in range(TRAIN, PASSES)],
              "--out", str(folder / "scan"))
    out = folder / "map" / "map.csv"
    out.parent.mkdir(exist_ok=True)
    railwatch("track-map", "--events", str(folder / "scan"), "--out", str(out),
              "--assets", str(folder / "track.assets.csv"))
    return out


def scored(work: Path, seed: int) -> dict[str, Any]:
    """One line's map against its truth."""
    out = mapped(work, seed)
    folder = out.parent.parent
    places = [r for r in read_csv(out) if float(r["false_per_km"] or "inf") <= REPORT_PER_KM]
    defects = read_csv(folder / "track.defects.csv")

    def growth(d: dict[str, str]) -> float:
        found = re.search(r"growth=([0-9.]+)", d["detail"])
        return float(found.group(1)) if found else 1.0

    def near(p: dict[str, str], d: dict[str, str]) -> bool:
        x, lo = float(p["position_m"]), float(d["position_m"])
        return max(lo - x, x - lo - float(d["length_m"]), 0.0) <= TOLERANCE_M

    rows = {"grew": [], "grew_less": [], "stable": [], "ratios": []}
    for d in defects:
        on = [p for p in places if near(p, d)]
        if not on:
            continue
        best = max(on, key=lambda p: float(p["evidence"]))
        flag = best["growing"] == "yes"
        g = growth(d)
        key = "grew" if g >= 1.5 else "grew_less" if g > 1.0 else "stable"
        rows[key].append(flag)
        if key == "grew" and flag:
            rows["ratios"].append((float(best["growth"]), g))
    growing = [d for d in defects if growth(d) > 1.0]
    others = [p for p in places if not any(near(p, d) for d in growing)]
    rows["places"] = [p["growing"] == "yes" for p in others]
    oracle = oracle_trends(folder)
    rows["oracle_grew"] = [oracle[d["defect"]] for d in defects
                           if growth(d) >= 1.5 and d["defect"] in oracle]
    rows["oracle_stable"] = [oracle[d["defect"]] for d in defects
                             if growth(d) == 1.0 and d["defect"] in oracle]
    return rows


def oracle_trends(folder: Path) -> dict[str, bool]:
    """Per squat crossed by the mapped passes, whether the trend test flags what the squat
    does to the axle box: per pass the peak |pass − clean twin| of the axle-box channel over
    its rail within 50 ms of the crossing (what the data allow: no detector, no noise
    estimate, the defect's own response), with the pass's speed there, the map's test."""
    import json

    import pandas as pd

    from railwatch.trackmap import trends

    info = json.loads((folder / "physics.json").read_text())
    fs, passes = float(info["fs"]), info["passes"][TRAIN:]
    t = trends.days([pd.Timestamp(p["started_s"], unit="s").isoformat() for p in passes])
    peak: dict[str, np.ndarray] = {}
    speed: dict[str, np.ndarray] = {}
    for j, entry in enumerate(passes):
        name = entry["pass"]
        signal = pd.read_parquet(folder / f"{name}.parquet")
        twin = pd.read_parquet(folder / "twins" / f"{name}.parquet")
        for r in read_csv(folder / f"{name}.defects.csv"):
            if r["kind"] != "squat":
                continue
            i, w = int(round(float(r["center_s"]) * fs)), int(0.05 * fs)
            diff = (signal[r["channel"]].to_numpy()[max(i - w, 0):i + w]
                    - twin[r["channel"]].to_numpy()[max(i - w, 0):i + w])
            peak.setdefault(r["defect"], np.full(len(passes), np.nan))[j] = np.abs(diff).max()
            speed.setdefault(r["defect"], np.full(len(passes), np.nan))[j] = float(
                r["speed_ms"])
    return {k: trends.trend(np.log(np.maximum(v, 1e-9)), t, speed[k]).growing
            for k, v in peak.items()}


def pct(flags: list[bool]) -> str:
    return f"{100 * np.mean(flags):.0f} % ({sum(flags)}/{len(flags)})" if flags else "-"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, default=Path("runs/track-map-trends"))
    parser.add_argument("--out", type=Path, default=Path(PAGE))
    args = parser.parse_args()

    started = time.perf_counter()
    head, items = page_head(__name__, __doc__)
    lines = ["# Trends over dated passes: growing squats on physics lines", "", head, "",
             "| line | squats grown by half or more, flagged | oracle | grown 1.2-1.5×, "
             "flagged | stable defects flagged | oracle: stable squats flagged | every other "
             "reported place flagged | growth read / true depth ratio (median of the flagged) "
             "|", "|---|---|---|---|---|---|---|---|"]
    total: dict[str, list[Any]] = {"grew": [], "grew_less": [], "stable": [], "places": [],
                                   "ratios": [], "oracle_grew": [], "oracle_stable": []}
    for seed in (DEV, *TEST):
        r = scored(args.work, seed)
        if seed != DEV:
            for k in total:
                total[k] += r[k]
        ratio = (f"{np.median([a for a, _ in r['ratios']]):.2f} / "
                 f"{np.median([b for _, b in r['ratios']]):.2f}") if r["ratios"] else "-"
        lines.append(f"| {seed}{' (development)' if seed == DEV else ''} | {pct(r['grew'])} | "
                     f"{pct(r['oracle_grew'])} | {pct(r['grew_less'])} | {pct(r['stable'])} | "
                     f"{pct(r['oracle_stable'])} | {pct(r['places'])} | {ratio} |")
        print(lines[-1], flush=True)
    ratio = (f"{np.median([a for a, _ in total['ratios']]):.2f} / "
             f"{np.median([b for _, b in total['ratios']]):.2f}") if total["ratios"] else "-"
    lines.append(f"| **test lines {TEST[0]}-{TEST[-1]}** | **{pct(total['grew'])}** | "
                 f"{pct(total['oracle_grew'])} | {pct(total['grew_less'])} | "
                 f"**{pct(total['stable'])}** | {pct(total['oracle_stable'])} | "
                 f"{pct(total['places'])} | {ratio} |")
    lines += ["", "Columns:", "", *items, "",
              f"Made in {time.perf_counter() - started:.0f} s (lines reused where kept).", ""]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
