"""The asset register on the physics test tracks: places labelled, defects left unexplained.

Test tracks 200-202 of `benchmarks/physics.py` (nothing chosen on them; same `--work`), the
README's workflow with every default (the matched filter trained on passes 1-2, `scan`), the
5-pass maps of passes 3-7 and 8-12 and the 10-pass map, with positions from odometry alone
(truth within ±5 m) and GNSS-aided (±3 m). The register is what a railway knows: every
turnout's switch and crossing nose, bridge transition and level crossing (the track's
features), and every rail joint as an insulated joint (the world's joints, dipped 0.2-3 mm: in
a register they are assets, and a dipped one is an asset that answers more than its kind).
`track-map --assets` with its default tolerance (5 m). Measured:

1. **Assets labelled**: of the assets with a reported place within the truth tolerance, the
   share whose place is labelled with that asset (or, for a turnout's switch and crossing
   nose, which touch, with either);
2. **Defects left unexplained**: of the defects not in the register (squats, welds, steps,
   corrugation) that the plain map finds, the share whose place is labelled unexplained (a
   defect within 5 m of an asset is explained away: counted apart);
3. **Unexplained false places** per km: labelled unexplained and near no defect or asset;
4. **Joints against their kind**: each joint's response against its impact (the median over
   the map's passes of the highest |acceleration| of the axle box over its rail within 0.1 s
   of the crossing, read from the recordings: what the data show) and its `kind_z` against
   its dip's depth (Spearman's rank correlations over the maps' joints), and the depths of
   those flagged abnormal.

Second table, **a register learned from the passes** (`track-map --learn-assets`, no
register given; its rule was developed on the development tracks 100-105, its crossing noses
also on the trends benchmark's lines 500, 504-506 and 510-511): the same maps,
scored against the track's features alone (its joints are then defects: nothing tells a
learned register they are insulated joints). Assets labelled: of the features with a reported
place, the share whose place is labelled with a learned asset, in all and per kind.

Run after `benchmarks/physics.py` (its maps are reused); about 5 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import railwatch, read_csv
from benchmarks.track_map import page_head

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ("physics",)
PAGE = "docs/results/track-map/track-map-assets.md"
MINUTES = 5

SEEDS = (200, 201, 202)
MAPS = ("n5-0", "n5-5", "n10-0")
POSITIONING = {"odometry alone": ("", 5.0), "GNSS-aided": ("-gnss", 3.0)}
#: The world's feature kinds as a register names them.
KIND_NAMES = {"switch": "switch", "crossing": "crossing", "transition": "bridge transition",
              "level-crossing": "level crossing"}
REPORT_PER_KM = 0.1



def register(folder: Path) -> Path:
    """The track's register: its features and its joints, by id."""
    out = folder / "register.csv"
    rows = [{"id": f"F{r['defect']}", "kind": KIND_NAMES[r["kind"]],
             "position_m": r["position_m"], "length_m": r["length_m"]}
            for r in read_csv(folder / "track.features.csv")]
    rows += [{"id": f"J{r['defect']}", "kind": "insulated joint", "position_m": r["position_m"],
              "length_m": r["length_m"]}
             for r in read_csv(folder / "track.defects.csv") if r["kind"] == "joint"]
    with open(out, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=["id", "kind", "position_m", "length_m"],
                                lineterminator="\n")
        writer.writeheader()
        writer.writerows(sorted(rows, key=lambda r: float(r["position_m"])))
    return out


def distance(x: float, lo: float, hi: float) -> float:
    return max(lo - x, x - hi, 0.0)


def one_map(folder: Path, name: str, tol: float, learn: bool = False) -> dict[str, Any]:
    """``track-map --assets`` (or ``--learn-assets``) of one of the physics bench's maps,
    scored."""
    return scored(folder, folder / "maps" / name, tol, learn)


def scored(folder: Path, events: Path, tol: float, learn: bool = False) -> dict[str, Any]:
    """``track-map --assets`` of the scan folder ``events`` over the track ``folder``, scored;
    ``learn``: ``--learn-assets`` instead, scored against the track's features (its joints are
    then defects: a learned register cannot know them for insulated joints)."""
    reg = register(folder)
    out = events / ("learned-map.csv" if learn else "register-map.csv")
    railwatch("track-map", "--events", str(events), "--out", str(out),
              *(["--learn-assets"] if learn else ["--assets", str(reg)]))
    places = [r for r in read_csv(out) if float(r["false_per_km"] or "inf") <= REPORT_PER_KM]
    assets = {r["id"]: (float(r["position_m"]), float(r["position_m"]) + float(r["length_m"]),
                        r["kind"]) for r in read_csv(reg)
              if not (learn and r["kind"] == "insulated joint")}
    defects = [r for r in read_csv(folder / "track.defects.csv")
               if learn or r["kind"] != "joint"]
    stretch = {r["defect"]: (float(r["position_m"]),
                             float(r["position_m"]) + float(r["length_m"])) for r in defects}
    km = json.loads((folder / "physics.json").read_text())["world"]["length_m"] / 1000
    labelled, explained_away, unexplained_found, defects_found = [], [], 0, 0
    false_unexplained = 0
    by_kind: dict[str, list[bool]] = {}
    for lo, hi, kind in assets.values():
        near = [p for p in places if distance(float(p["position_m"]), lo, hi) <= tol]
        if near:
            ok_ids = {b for b, (blo, bhi, _) in assets.items()
                      if any(distance(float(p["position_m"]), blo, bhi) <= tol for p in near)}
            ok = any(p["asset"] != "unexplained" for p in near) if learn else any(
                p["asset"] in ok_ids for p in near)
            labelled.append(ok)
            by_kind.setdefault(kind, []).append(ok)
    for d, (lo, hi) in stretch.items():
        near = [p for p in places if distance(float(p["position_m"]), lo, hi) <= tol]
        if not near:
            continue
        defects_found += 1
        if any(p["asset"] == "unexplained" for p in near):
            unexplained_found += 1
        else:
            explained_away.append(d)
    for p in places:
        x = float(p["position_m"])
        if p["asset"] == "unexplained" and not any(
                distance(x, lo, hi) <= tol for lo, hi in stretch.values()) and not any(
                distance(x, lo, hi) <= tol for lo, hi, _ in assets.values()):
            false_unexplained += 1
    if learn:
        return {"labelled": labelled, "defects_found": defects_found,
                "unexplained_found": unexplained_found, "explained_away": explained_away,
                "false_unexplained": false_unexplained, "km": km, "by_kind": by_kind}
    joints = [(float(r["kind_z"]), r["abnormal"] == "yes", r["id"], float(r["response"]))
              for r in read_csv(out.with_name("register-map.assets.csv"))
              if r["kind"] == "insulated joint" and r["kind_z"]]
    depth = {f"J{r['defect']}": float(r["depth_mm"])
             for r in read_csv(folder / "track.defects.csv") if r["kind"] == "joint"}
    names = sorted(p.name[: -len(".scan.json")] for p in out.parent.glob("*.scan.json"))
    impact = joint_impacts(folder, names)
    return {"labelled": labelled, "defects_found": defects_found,
            "unexplained_found": unexplained_found, "explained_away": explained_away,
            "false_unexplained": false_unexplained, "km": km,
            "joints": [(z, flag, depth[i], resp, impact.get(i, np.nan))
                       for z, flag, i, resp in joints]}


def share(flags: list[bool]) -> str:
    return f"{100 * np.mean(flags):.0f} % ({sum(flags)}/{len(flags)})" if flags else "-"


def joint_impacts(folder: Path, names: list[str]) -> dict[str, float]:
    """Per joint, the median over the passes ``names`` of the highest |acceleration| of the
    axle box over its rail within 0.1 s of the crossing (m/s²): what the joint does to the
    vehicle, read from the recordings."""
    import pandas as pd

    fs = json.loads((folder / "physics.json").read_text())["fs"]
    peaks: dict[str, list[float]] = {}
    for name in names:
        signal = pd.read_parquet(folder / f"{name}.parquet")
        for r in read_csv(folder / f"{name}.defects.csv"):
            if r["kind"] == "joint":
                j = int(round(float(r["center_s"]) * fs))
                seg = signal[r["channel"]].to_numpy()[max(0, j - int(0.1 * fs)):
                                                      j + int(0.1 * fs)]
                peaks.setdefault(f"J{r['defect']}", []).append(float(np.abs(seg).max()))
    return {k: float(np.median(v)) for k, v in peaks.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, default=Path("runs/physics"))
    parser.add_argument("--out", type=Path, default=Path(PAGE))
    args = parser.parse_args()
    from scipy.stats import spearmanr

    started = time.perf_counter()
    head, items = page_head(__name__, __doc__)
    lines = ["# The asset register on the physics test tracks", "", head, "",
             "| positions | maps | assets labelled | defects left unexplained | explained away "
             "| unexplained false places per km | joints: Spearman (response, impact) | "
             "Spearman (kind_z, depth) | joints flagged abnormal (depth, mm) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for label, (suffix, tol) in POSITIONING.items():
        for maps in (("n5-0", "n5-5"), ("n10-0",)):
            runs = [one_map(args.work / f"track{seed}{suffix}", m, tol)
                    for seed in SEEDS for m in maps]
            lab = [v for r in runs for v in r["labelled"]]
            found = sum(r["defects_found"] for r in runs)
            unexpl = sum(r["unexplained_found"] for r in runs)
            away = sum(len(r["explained_away"]) for r in runs)
            false = sum(r["false_unexplained"] for r in runs)
            km = sum(r["km"] for r in runs)
            joints = [j for r in runs for j in r["joints"]]
            rho = spearmanr([j[0] for j in joints], [j[2] for j in joints]).statistic
            rho_impact = spearmanr([j[3] for j in joints], [j[4] for j in joints]).statistic
            flagged = sorted(j[2] for j in joints if j[1])
            lines.append(
                f"| {label} | {len(runs)} × {maps[0][1:].split('-')[0]} passes | "
                f"{100 * np.mean(lab):.0f} % ({sum(lab)}/{len(lab)}) | "
                f"{100 * unexpl / max(found, 1):.0f} % ({unexpl}/{found}) | {away} | "
                f"{false / km:.2f} | {rho_impact:.2f} | {rho:.2f} ({len(joints)} joints) | "
                f"{', '.join(f'{d:.2f}' for d in flagged) or 'none'} |")
            print(lines[-1], flush=True)
    depths = sorted(float(r["depth_mm"]) for seed in SEEDS for r in read_csv(
        args.work / f"track{seed}" / "track.defects.csv") if r["kind"] == "joint")
    lines += ["", "Columns:", "", *items]
    lines += ["", f"The test tracks' joints, depth in mm: {', '.join(f'{d:.2f}' for d in depths)}."]
    assert __doc__ is not None
    lines += ["", " ".join(__doc__.split("\n\n")[3].split()), "",
              "| positions | maps | assets labelled | switches | bridge transitions | level "
              "crossings | crossing noses | defects left unexplained | explained away | "
              "unexplained false places per km |", "|---|---|---|---|---|---|---|---|---|---|"]
    for label, (suffix, tol) in POSITIONING.items():
        for maps in (("n5-0", "n5-5"), ("n10-0",)):
            runs = [one_map(args.work / f"track{seed}{suffix}", m, tol, learn=True)
                    for seed in SEEDS for m in maps]
            lab = [v for r in runs for v in r["labelled"]]
            kinds = {k: [v for r in runs for v in r["by_kind"].get(k, [])]
                     for k in ("switch", "bridge transition", "level crossing", "crossing")}
            found = sum(r["defects_found"] for r in runs)
            unexpl = sum(r["unexplained_found"] for r in runs)
            lines.append(
                f"| {label} | {len(runs)} × {maps[0][1:].split('-')[0]} passes | "
                f"{share(lab)} | " + " | ".join(share(v) for v in kinds.values())
                + f" | {share([True] * unexpl + [False] * (found - unexpl))} | "
                f"{sum(len(r['explained_away']) for r in runs)} | "
                f"{sum(r['false_unexplained'] for r in runs) / sum(r['km'] for r in runs):.2f} |")
            print(lines[-1], flush=True)
    lines += ["", f"Made in {time.perf_counter() - started:.0f} s.", ""]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
