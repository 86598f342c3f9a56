"""Trends over dated passes on physics lines whose squats grow: growing places flagged, stable
ones not.

Physics lines of 5 km (`railwatch simulate --passes 12 --start 2026-01-05T06:00Z --every-days 7
--growing 0.5`: half of the squats deepen linearly in time to 1.2-3.0 times their first depth
at the last pass and lengthen with it, as the track's squats are long at that depth; every
default otherwise), the README's workflow (the matched filter trained on passes 1-2 with
defaults, `scan` of passes 3-12, ten weeks), `track-map` with the line's register (`--assets
track.assets.csv`). The trend's rule was developed on lines 500 and 504-506 (the per-place
speed slope, the flag's p: docs/maintenance.md); lines 501-503 are test lines, nothing chosen
on them; lines 510-511 are made differently (a slow line, 8-15 m/s, its passes a fortnight
apart: twenty weeks), and lines 520-521 (recorded at 1 kHz instead of 2). A defect is on the
map when a reported place lies within 5 m of it (odometry alone). Measured:

1. **Growing**: of the squats on the map that grew by half or more (`growth` >= 1.5 in
   `track.defects.csv`), the share flagged `growing`; and of those that grew less (1.2-1.5);
2. **Stable**: of the defects on the map that did not grow, the share flagged; and of every
   reported place not on a growing squat (defects, features, anything), the share flagged;
3. **Growth**: the median of the map's `growth` (the fitted strength ratio, last pass over
   first) over the flagged squats, beside the median of their true depth ratio;
4. **Oracle**: the same test on what each squat does to the axle box, per pass the peak of
   the low band of pass − clean twin over its rail within 50 ms of the crossing (every squat
   the passes crossed, on the map or not): what the data allow a trend to see. A place's
   strength is the low band's peak where the scan kept it (`trends.low_band`: |acceleration|
   below 200 Hz, at field rate as here).

Second table, **the places on the earth** (`track-map --geojson`: each place's latitude and
longitude, the median over the passes of the pass's GNSS fix where it crossed the place): for
every defect on the map, the distance from its place's point to where the defect truly lies on
the line, beside the distance along the track from the place's position (the map's frame:
the passes' odometry), median and 95th percentile.

Third table, **the issue's maintenance targets** on the same maps, with the line's register
(`--assets track.assets.csv`: its turnouts, bridge transitions and level crossings) and with a
register learned from the passes instead (`--learn-assets`, its rule developed on the physics
development tracks 100-105, its crossing noses also on lines 500, 504-506 and 510-511): of
every defect of the line, the share reported as an unexplained
place within 2 m (on the earth by the places' GNSS points; along the track in the map's frame,
which carries the odometry's common error) and within 5 m along; of the register's assets with
a reported place within 5 m, the share labelled right (the register: with that asset, or with
the asset it touches, a turnout's switch and crossing nose; learned: with a learned asset);
unexplained places within 5 m of no defect or asset, per km.

Run: `make bench-track-map-trends` (about 25 minutes on 2 cores; the lines are kept in
`--work` and reused).
"""

from __future__ import annotations

import argparse
import json
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
MINUTES = 25

DEV, TEST = (500, 504, 505, 506), (501, 502, 503)
#: Lines made differently, to see whether the rule carries over: a slow line (8-15 m/s instead
#: of the default 10-30) whose passes come a fortnight apart, twenty weeks in all; a line
#: recorded at 1 kHz (a logger's lower rate; the low band's 200 Hz still well inside it).
OTHER = {510: ("--speed", "8-15", "--every-days", "14"), 511: ("--speed", "8-15",
                                                              "--every-days", "14"),
         520: ("--fs", "1000"), 521: ("--fs", "1000")}
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
        railwatch("simulate", "--out", str(folder), "--seed", str(seed), *SIMULATE,
                  *OTHER.get(seed, ()))
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
              "--assets", str(folder / "track.assets.csv"), "--geojson",
              str(out.with_suffix(".geojson")))
    learned = out.with_name("learned.csv")
    railwatch("track-map", "--events", str(folder / "scan"), "--out", str(learned),
              "--learn-assets", "--geojson", str(learned.with_suffix(".geojson")))
    return out


def maintenance(folder: Path, out: Path, learn: bool) -> dict[str, Any]:
    """One map of a line (with its register, or ``learn``: the learned one) against the
    line's truth: each defect reported as an unexplained place within 2 m (on the earth, by
    the places' GNSS points; along the track, in the map's frame) or 5 m (along); each asset
    (the line's register) with a place, labelled right; unexplained places near nothing."""
    places = [r for r in read_csv(out) if float(r["false_per_km"] or "inf") <= REPORT_PER_KM]
    defects = read_csv(folder / "track.defects.csv")
    assets = read_csv(folder / "track.assets.csv")
    where = earth(folder, out.with_suffix(".geojson"))

    def stretch(r: dict[str, str]) -> tuple[float, float]:
        return float(r["position_m"]), float(r["position_m"]) + float(r["length_m"])

    def along(p: dict[str, str], r: dict[str, str]) -> float:
        lo, hi = stretch(r)
        return max(lo - float(p["position_m"]), float(p["position_m"]) - hi, 0.0)

    def on_earth(p: dict[str, str], r: dict[str, str]) -> float:
        f = where.get(int(p["rank"]))
        return min(f(x) for x in (*stretch(r), sum(stretch(r)) / 2)) if f else np.inf

    unexplained = [p for p in places if p["asset"] == "unexplained"]
    rows: dict[str, Any] = {
        "earth_2m": [any(on_earth(p, d) <= 2.0 for p in unexplained) for d in defects],
        "along_2m": [any(along(p, d) <= 2.0 for p in unexplained) for d in defects],
        "along_5m": [any(along(p, d) <= TOLERANCE_M for p in unexplained) for d in defects],
        "labelled": [], "km": json.loads((folder / "physics.json").read_text())["world"][
            "length_m"] / 1000}
    for a in assets:
        near = [p for p in places if along(p, a) <= TOLERANCE_M]
        if near:  # a turnout's switch and crossing nose may touch: either label is right
            right = {b["id"] for b in assets if any(along(p, b) <= TOLERANCE_M for p in near)}
            rows["labelled"].append(any(p["asset"] != "unexplained" if learn
                                        else p["asset"] in right for p in near))
    rows["false"] = sum(not any(along(p, r) <= TOLERANCE_M for r in (*defects, *assets))
                        for p in unexplained)
    return rows


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

    rows = {"grew": [], "grew_less": [], "stable": [], "ratios": [], "earth_m": [],
            "along_m": []}
    where = earth(folder, out.with_suffix(".geojson"))
    for d in defects:
        on = [p for p in places if near(p, d)]
        if not on:
            continue
        best = max(on, key=lambda p: float(p["evidence"]))
        centre = float(d["position_m"]) + float(d["length_m"]) / 2
        rows["along_m"].append(abs(float(best["position_m"]) - centre))
        if int(best["rank"]) in where:
            rows["earth_m"].append(where[int(best["rank"])](centre))
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


def earth(folder: Path, geojson: Path) -> dict[int, Any]:
    """Map rank -> a function of a chainage (m): how far (m) the place's point lies from that
    chainage on the line (the simulator's, without the fixes' error)."""
    import json

    from railwatch.physics import gnss
    from railwatch.physics.files import line_of
    from railwatch.trackmap.geo import plane

    info = json.loads((folder / "physics.json").read_text())
    s, east, north = line_of(float(info["world"]["length_m"]), int(info["seed"]))
    out = {}
    for f in json.loads(geojson.read_text())["features"]:
        if f["properties"]["kind"] != "place" or f["geometry"] is None:
            continue
        lon, lat = f["geometry"]["coordinates"]

        def off(x: float, lat: float = lat, lon: float = lon) -> float:
            want_lat, want_lon = gnss.to_degrees(np.interp(x, s, east), np.interp(x, s, north))
            return float(np.hypot(*plane(lat, lon, float(want_lat), float(want_lon))))

        out[int(f["properties"]["rank"])] = off
    return out


def oracle_trends(folder: Path) -> dict[str, bool]:
    """Per squat crossed by the mapped passes, whether the trend test flags what the squat
    does to the axle box: per pass the peak of the low band (what the map's trend measures,
    `trends.low_band`) of pass − clean twin of the axle-box channel over its rail within 50 ms
    of the crossing (what the data allow: no detector, no noise, the defect's own response),
    with the pass's speed there, the map's test (the low band kept in its units)."""
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
        squats = [r for r in read_csv(folder / f"{name}.defects.csv") if r["kind"] == "squat"]
        channels = sorted({r["channel"] for r in squats})
        if not channels:
            continue
        diff = (pd.read_parquet(folder / f"{name}.parquet", columns=channels).to_numpy()
                - pd.read_parquet(folder / "twins" / f"{name}.parquet",
                                  columns=channels).to_numpy())
        band = trends.low_band(diff, fs)
        assert band is not None, "the physics world records at field rate"
        for r in squats:
            i, w = int(round(float(r["center_s"]) * fs)), int(0.05 * fs)
            peak.setdefault(r["defect"], np.full(len(passes), np.nan))[j] = \
                band[max(i - w, 0):i + w, channels.index(r["channel"])].max()
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
                                   "ratios": [], "oracle_grew": [], "oracle_stable": [],
                                   "earth_m": [], "along_m": []}
    located = ["| line | defects on the map | on the earth (GNSS): median, 95th pct | along "
               "the track (odometry): median, 95th pct |", "|---|---|---|---|"]

    def spread(v: list[float]) -> str:
        return f"{np.median(v):.1f} m, {np.percentile(v, 95):.1f} m" if v else "-"

    for seed in (*DEV, *TEST):
        r = scored(args.work, seed)
        if seed not in DEV:
            for k in total:
                total[k] += r[k]
        ratio = (f"{np.median([a for a, _ in r['ratios']]):.2f} / "
                 f"{np.median([b for _, b in r['ratios']]):.2f}") if r["ratios"] else "-"
        lines.append(f"| {seed}{' (development)' if seed in DEV else ''} | {pct(r['grew'])} | "
                     f"{pct(r['oracle_grew'])} | {pct(r['grew_less'])} | {pct(r['stable'])} | "
                     f"{pct(r['oracle_stable'])} | {pct(r['places'])} | {ratio} |")
        located.append(f"| {seed}{' (development)' if seed in DEV else ''} | "
                       f"{len(r['along_m'])} | {spread(r['earth_m'])} | "
                       f"{spread(r['along_m'])} |")
        print(lines[-1], located[-1], flush=True)
    ratio = (f"{np.median([a for a, _ in total['ratios']]):.2f} / "
             f"{np.median([b for _, b in total['ratios']]):.2f}") if total["ratios"] else "-"
    lines.append(f"| **test lines {TEST[0]}-{TEST[-1]}** | **{pct(total['grew'])}** | "
                 f"{pct(total['oracle_grew'])} | {pct(total['grew_less'])} | "
                 f"**{pct(total['stable'])}** | {pct(total['oracle_stable'])} | "
                 f"{pct(total['places'])} | {ratio} |")
    for seed in OTHER:
        r = scored(args.work, seed)
        ratio = (f"{np.median([a for a, _ in r['ratios']]):.2f} / "
                 f"{np.median([b for _, b in r['ratios']]):.2f}") if r["ratios"] else "-"
        lines.append(f"| {seed} (made differently: {' '.join(OTHER[seed])}) | {pct(r['grew'])} "
                     f"| {pct(r['oracle_grew'])} | {pct(r['grew_less'])} | {pct(r['stable'])} | "
                     f"{pct(r['oracle_stable'])} | {pct(r['places'])} | {ratio} |")
        print(lines[-1], flush=True)
    located.append(f"| **test lines {TEST[0]}-{TEST[-1]}** | {len(total['along_m'])} | "
                   f"**{spread(total['earth_m'])}** | {spread(total['along_m'])} |")
    assert __doc__ is not None
    lines += ["", " ".join(__doc__.split("\n\n")[3].split()), "", *located]
    lines += ["", " ".join(__doc__.split("\n\n")[4].split()), "",
              "| line | register | defects reported unexplained: within 2 m on the earth "
              "(GNSS) | within 2 m along the track | within 5 m along | assets with a place, "
              "labelled | unexplained false places per km |", "|---|---|---|---|---|---|---|"]
    for learn in (False, True):
        both: dict[str, list[Any]] = {}
        for seed in (*DEV, *TEST):
            folder = args.work / f"line{seed}"
            r = maintenance(folder, folder / "map" / ("learned.csv" if learn else "map.csv"),
                            learn)
            if seed not in DEV:
                for k, v in r.items():
                    both.setdefault(k, []).extend(v if isinstance(v, list) else [v])
            lines.append(f"| {seed}{' (development)' if seed in DEV else ''} | "
                         f"{'learned' if learn else 'given'} | {pct(r['earth_2m'])} | "
                         f"{pct(r['along_2m'])} | {pct(r['along_5m'])} | {pct(r['labelled'])} | "
                         f"{r['false'] / r['km']:.2f} |")
        lines.append(f"| **test lines {TEST[0]}-{TEST[-1]}** | {'learned' if learn else 'given'}"
                     f" | **{pct(both['earth_2m'])}** | {pct(both['along_2m'])} | "
                     f"{pct(both['along_5m'])} | **{pct(both['labelled'])}** | "
                     f"**{sum(both['false']) / sum(both['km']):.2f}** |")
    lines += ["", "Columns:", "", *items, "",
              f"Made in {time.perf_counter() - started:.0f} s (lines reused where kept).", ""]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
