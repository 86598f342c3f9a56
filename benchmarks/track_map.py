"""The track map on synthesised tracks: recall of the true defect positions and false locations
per km against the number of passes (1, 2, 5, 10), for both ways of mapping (evidence fused from
every pass's scores, and votes of thresholded events), and the scan's throughput, local and on
Ray.

For each kind of nuisance (stage-5-like, stage-8-like, both with loud stretches of track), one
10-km track with 40 defects and 12 passes (`railwatch generate-run --passes 12`): passes 1-2
train the detector (`train --recordings`, no labels), passes 3-12 are scanned (`scan`) and
mapped (`track-map`). The reporting rule (`--min-share`) is chosen on a second track of each
kind (other seed: the development track), at 5 passes, as the largest recall with at most 0.1
false locations per km; the figures are those of the test track. Two odometries: the defaults
of `generate-run --passes` (odometry alone: offset 1 m, drift 0.05 %, walk 0.3 m per √km) and a
GNSS-aided one (offset 1 m, drift 0.01 %, walk 0.1 m per √km); the same scan's events, their
positions read from each odometry's position along the pass at the event's peak time. The scan
threshold is chosen on the development track with the share, among 1, 0.75 and 0.5 × the
model's event threshold: one scan at 0.5 ×, its events kept where their peak score reaches the
higher thresholds (the rows "model's" keep the model's threshold). The fused map (`track-map`'s
default) chooses nothing on the development track: it reports places whose evidence passes
shifted at random reach at most 0.1 times per km (its default), and takes its events (for the
alignment) at the model's threshold.

Run: `make bench-track-map` (about 50 minutes on 2 cores). `--train 6 --detectors context-glr
--no-throughput --out docs/results/track-map/track-map-train6.md` trains on 6 passes instead of
2 (16 laid out, the last 10 mapped; about 30 minutes).
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import command as command_line
from benchmarks.common import railwatch

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/track-map/track-map.md"
MINUTES = 50

KINDS = {"stage 5": ["--stage", "5", "--loud-stretches"],
         "stage 8": ["--stage", "8", "--loud-stretches"]}
#: Which detectors run on which nuisance (aft-attention finds few defects per pass: stage 5 only).
RUNS = (("stage 5", "context-glr"), ("stage 5", "aft-attention"), ("stage 8", "context-glr"),
        ("stage 5", "matched-filter"), ("stage 8", "matched-filter"),
        ("stage 5", "matched-filter-wheel"), ("stage 8", "matched-filter-wheel"))
#: What the page says of `scan`'s throughput when `--no-throughput` skipped it.
NOT_MEASURED = ("`scan` throughput: not measured in this run (`--no-throughput`); the last "
                "figures, with their date and machine: docs/measurements.md, \"Track map from "
                "repeated passes\".")
#: Labels of runs that train a registry detector with `train` flags: the matched filter with
#: the wheel comb (`train --wheel-comb`).
TRAIN_FLAGS = {"matched-filter-wheel": ("matched-filter", ("--wheel-comb",))}
ODOMETRIES = {"odometry alone": None, "GNSS-aided": (1.0, 0.0001, 0.1)}
SEEDS = {"test": 11, "dev": 12}
#: The eight development tracks of the track-map benchmarks that measure on several (seeds
#: 12-19; the test track, seed 11, is never among them): role name -> seed.
DEV_ROLES = {"dev": 12, **{f"dev{seed - 11}": seed for seed in range(13, 20)}}
PASSES, TRAIN = 12, 2
COUNTS = (1, 2, 5, 10)
SHARES = (0.2, 0.3, 0.4, 0.5, 0.6)
#: Scan thresholds, × the model's event threshold: a map of repeated passes can afford a more
#: sensitive scan, since what does not repeat is dropped.
FACTORS = (1.0, 0.75, 0.5)
TARGET_RECALL, TARGET_FALSE = 0.95, 0.1


def page_head(module: str, doc: str) -> tuple[str, list[str]]:
    """How a results page of the track-map benchmarks opens: the command that made it (with
    this run's arguments), the date, the CPU and the first paragraph of the script's docstring
    after its title; and the numbered items of the next paragraph, one line each."""
    from railwatch.machine import cpu_name

    parts = doc.split("\n\n")
    command = (f"Command: `{command_line(module)}`, "
               f"{datetime.date.today().isoformat()}, {cpu_name()}, 2 cores. "
               + " ".join(parts[1].split()))
    items = [" ".join(item.split()) for item in re.split(r"\n(?=\d\. )", parts[2])] \
        if len(parts) > 2 else []
    return command, items


def track(work: Path, kind: str, role: str) -> Path:
    folder = work / (f"{kind.replace(' ', '')}-{role}"
                     + ("" if TRAIN == 2 else f"-train{TRAIN}"))
    if not (folder / "track.defects.csv").exists():
        railwatch("generate-run", "--passes", str(PASSES), "--track-km", "10",
                  "--track-defects", "40", "--seed", str(SEEDS[role]), *KINDS[kind],
                  "--out", str(folder))
    return folder


def scanned(folder: Path, detector: str, factor: float = 1.0, settings: tuple[str, ...] = (),
            label: str | None = None) -> Path:
    """Train ``detector`` (with ``--set`` ``settings``) on the first passes, scan the others
    with ``factor`` × the model's event threshold; the scan folder. ``label`` names the model
    and scan folders (default: the detector); a label of TRAIN_FLAGS trains its detector with
    its flags."""
    from railwatch.detection.pipeline import load_recording_model

    label = label or detector
    detector, flags = TRAIN_FLAGS.get(detector, (detector, ()))
    model = folder / f"model-{label}"
    if not (model / "detector.json").exists():
        train = [str(folder / f"pass{i:02d}.parquet") for i in range(1, TRAIN + 1)]
        sets = [arg for setting in settings for arg in ("--set", setting)]
        railwatch("train", "--detector", detector, *sets, *flags, "--recordings", *train,
                  "--layout", str(folder / "layout.toml"), "--out", str(model))
    out = folder / (f"scan-{label}" if factor == 1.0 else f"scan-{label}-x{factor:g}")
    test = [str(folder / f"pass{i:02d}.parquet") for i in range(TRAIN + 1, PASSES + 1)]
    lower = [] if factor == 1.0 else [
        "--threshold", repr(factor * load_recording_model(model).threshold)]
    railwatch("scan", "--model", str(model), "--recordings", *test, "--out", str(out), *lower)
    return out


def above(scan: Path, factor: float, low: float) -> Path:
    """The events of ``scan`` (made at ``low`` × the model's threshold) whose peak score reaches
    ``factor`` × it: the scan at that threshold, up to how nearby events merge."""
    import csv
    import json
    import shutil

    from railwatch.trackmap import EVENTS_SUFFIX, PROFILE_SUFFIX, SCAN_SUFFIX

    if factor == low:
        return scan
    out = scan.with_name(f"{scan.name}-above-x{factor:g}")
    out.mkdir(exist_ok=True)
    for info_path in sorted(scan.glob(f"*{SCAN_SUFFIX}")):
        info = json.loads(info_path.read_text())
        threshold = float(info["threshold"]) * factor / low
        shutil.copy(info_path, out / info_path.name)
        name = info_path.name[: -len(SCAN_SUFFIX)]
        shutil.copy(scan / f"{name}{PROFILE_SUFFIX}", out / f"{name}{PROFILE_SUFFIX}")
        with open(scan / f"{name}{EVENTS_SUFFIX}", newline="") as fh:
            reader = csv.DictReader(fh)
            fields = list(reader.fieldnames or [])
            rows = [r for r in reader if float(r["score"]) >= threshold]
        with open(out / f"{name}{EVENTS_SUFFIX}", "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=fields, lineterminator="\n")
            writer.writeheader()
            writer.writerows(rows)
    return out


def curve(scan: Path, truth: Path, share: float | None) -> list[dict[str, float]]:
    """Recall and false locations per km from the first 1, 2, 5, 10 passes: the votes map
    reported at ``share``, or (``share`` None) the fused map at its default rule."""
    from railwatch import trackmap as tm
    from railwatch.evaluation import maps as em

    passes = tm.read_scan(scan)
    truth_m = em.read_truth(truth)
    rows = []
    for k in COUNTS:
        use = passes[:k]
        lo, hi = tm.covered_range(use)
        covered = em.on_stretch(truth_m, lo, hi)
        if share is None:
            shown = tm.reported_fused(tm.fused_map(use)[0])
        else:
            shown = tm.reported(tm.track_map(use), share, k)
        s = em.score_locations(shown, covered, hi - lo)
        rows.append({"passes": k, **s, "events_per_km": sum(len(p.position) for p in use)
                     / k / ((hi - lo) / 1000)})
    return rows


def choose_rule(scans: dict[float, Path], truth: Path) -> tuple[float, float]:
    """On the development track at 5 passes, over the scan thresholds (× the model's) and the
    shares: the largest recall with <= 0.1 false locations per km (ties: the higher threshold
    and share); if none qualifies, the fewest false."""
    results = []
    for factor, scan in scans.items():
        for share in SHARES:
            five = next(r for r in curve(scan, truth, share) if r["passes"] == 5)
            results.append((factor, share, five["recall"], five["false_per_km"]))
    ok = [r for r in results if r[3] <= TARGET_FALSE]
    if ok:
        best = max(ok, key=lambda r: (r[2], r[0], r[1]))
    else:
        best = min(results, key=lambda r: (r[3], -r[2]))
    return best[0], best[1]


def throughput(folder: Path, detector: str) -> dict[str, float]:
    """Recording-hours per hour of `scan`: in this process, and on a local Ray of 1 and 2
    workers (fresh scan folders, the same ten passes)."""
    import ray

    from railwatch.trackmap.scan import scan

    model = folder / f"model-{detector}"
    test = [folder / f"pass{i:02d}.parquet" for i in range(TRAIN + 1, PASSES + 1)]
    out = {}
    for label, workers in (("local", 0), ("ray, 1 worker", 1), ("ray, 2 workers", 2)):
        target = folder / f"throughput-{detector}-{workers}"
        if target.exists():
            import shutil

            shutil.rmtree(target)
        if workers:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        try:
            started = time.perf_counter()
            s = scan(model, test, target, executor="ray" if workers else "local")
            wall = time.perf_counter() - started
        finally:
            if workers:
                ray.shutdown()
        out[label] = s.recording_s / wall
    return out


def with_odometry(scan: Path, folder: Path, kind: str, role: str,
                  odometry: tuple[float, float, float] | None, suffix: str = "-gnss") -> Path:
    """The scan folder ``scan`` with every event's position read from another odometry of the
    same passes (None: as scanned), written beside it with ``suffix``; an odometry without
    errors, (0, 0, 0), gives the true positions."""
    import csv
    import json

    from railwatch.detection.pipeline import EVENT_FIELDS
    from railwatch.synthetic.track import Odometry, make_track, synthesize_pass
    from railwatch.trackmap import EVENTS_SUFFIX, PROFILE_SUFFIX, SCAN_SUFFIX

    if odometry is None:
        return scan
    out = scan.with_name(scan.name + suffix)
    out.mkdir(exist_ok=True)
    stage = int(KINDS[kind][1])
    track_ = make_track(10_000.0, 40, seed=SEEDS[role], stage=stage, loud_stretches=True)
    for info_path in sorted(scan.glob(f"*{SCAN_SUFFIX}")):
        name = info_path.name[: -len(SCAN_SUFFIX)]
        i = int(name[4:]) - 1  # passNN: the pass's index and seed as write_track gave them
        p = synthesize_pass(track_, seed=SEEDS[role] * 1000 + i + 1, fs=100.0,
                            direction=1 if i % 2 == 0 else -1, odometry=Odometry(*odometry))
        info = json.loads(info_path.read_text())
        info.update(position_first_m=float(p.run.position[0]),
                    position_last_m=float(p.run.position[-1]))
        (out / info_path.name).write_text(json.dumps(info))
        with np.load(scan / f"{name}{PROFILE_SUFFIX}") as f:
            profile = dict(f)
        profile["position_m"] = np.interp(profile["time_s"], p.run.time, p.run.position)
        np.savez(out / f"{name}{PROFILE_SUFFIX}", **profile)
        with open(scan / f"{name}{EVENTS_SUFFIX}", newline="") as fh:
            rows = list(csv.DictReader(fh))
        for r in rows:
            r["position_m"] = f"{np.interp(float(r['peak_s']), p.run.time, p.run.position):.4f}"
        with open(out / f"{name}{EVENTS_SUFFIX}", "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else EVENT_FIELDS,
                                    lineterminator="\n")
            writer.writeheader()
            writer.writerows(rows)
    return out


def main() -> None:
    np.seterr(all="ignore")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("runs/bench-track-map"))
    parser.add_argument("--out", type=Path, default=Path(PAGE))
    parser.add_argument("--train", type=int, default=2,
                        help="passes to train on (10 more are laid out and mapped)")
    parser.add_argument("--detectors", default=",".join(dict.fromkeys(d for _, d in RUNS)),
                        help="comma-separated: which of the runs' detectors to measure")
    parser.add_argument("--no-throughput", action="store_true",
                        help="skip the scan's throughput (measured with the default runs)")
    args = parser.parse_args()
    global PASSES, TRAIN
    TRAIN, PASSES = args.train, args.train + 10
    runs = [(kind, det) for kind, det in RUNS if det in args.detectors.split(",")]
    from railwatch.report.figures import save_figure
    from railwatch.report.pages import write_markdown

    args.work.mkdir(parents=True, exist_ok=True)
    results: dict[tuple[str, str, str, str], tuple[float, float | None,
                                                   list[dict[str, float]]]] = {}
    low = min(FACTORS)
    for kind, det in runs:
        test, dev = track(args.work, kind, "test"), track(args.work, kind, "dev")
        base = {role: scanned(folder, det, low) for role, folder in (("test", test),
                                                                   ("dev", dev))}
        for odo_name, odo in ODOMETRIES.items():
            per = {role: {f: with_odometry(above(base[role], f, low), folder, kind, role, odo)
                          for f in FACTORS}
                   for role, folder in (("test", test), ("dev", dev))}
            for label, factors in (("model's", (1.0,)), ("chosen", FACTORS)):
                factor, share = choose_rule({f: per["dev"][f] for f in factors},
                                            dev / "track.defects.csv")
                rows = curve(per["test"][factor], test / "track.defects.csv", share)
                results[(kind, det, odo_name, label)] = (factor, share, rows)
                print(kind, det, odo_name, label, factor, share, json.dumps(rows), flush=True)
            rows = curve(per["test"][1.0], test / "track.defects.csv", None)
            results[(kind, det, odo_name, "fused")] = (1.0, None, rows)
            print(kind, det, odo_name, "fused", json.dumps(rows), flush=True)
    speed = {} if args.no_throughput else throughput(track(args.work, "stage 5", "test"),
                                                      "context-glr")

    lines = [
        "# The track map against the number of passes",
        "",
        page_head(__name__, __doc__)[0]
        + ("" if TRAIN == 2 else f" Here {PASSES} passes, the first {TRAIN} trained on, the "
           "other 10 mapped."),
        "",
        "Recall: true defects (of those on the stretch the passes covered) with a reported "
        "location within ±2 m of the defect's stretch of rail; false: reported locations with no "
        f"true defect within ±2 m, per km covered. Targets: recall ≥ {TARGET_RECALL:.0%} and "
        f"≤ {TARGET_FALSE} false locations per km from 5 passes on.",
        "",
        "| nuisance | detector | odometry | method | scan threshold (× model's) | rule | "
        "passes | recall | false / km | events / km per pass |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (kind, det, odo, label), (factor, share, rows) in results.items():
        method = "fused" if share is None else "votes"
        rule = "0.1 / km by chance" if share is None else f"--min-share {share:g}"
        for r in rows:
            lines.append(f"| {kind} | {det} | {odo} | {method} | {factor:g} "
                         f"({'model' if share is None else label}) | {rule} | {r['passes']} | "
                         f"{r['recall']:.0%} | {r['false_per_km']:.2f} | "
                         f"{r['events_per_km']:.1f} |")
    if speed:
        lines += ["", "`scan` throughput (context-glr, stage 5, ten passes of about 7 minutes "
                  "at 2000 Hz), recording-hours per hour:", "", "| executor | rate |",
                  "|---|---|"]
        lines += [f"| {k} | {v:.0f} |" for k, v in speed.items()]
    else:
        lines += ["", NOT_MEASURED]
    figure = args.out.with_suffix(".png").name
    lines += ["", f"![recall and false locations against passes]({figure})"]
    save_figure(_figure(results), args.out.with_suffix(".png"))
    print(write_markdown(args.out, lines))


def _figure(results):  # type: ignore[no-untyped-def]
    from matplotlib import colormaps
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 3.8), layout="constrained")
    ax_r, ax_f = fig.subplots(1, 2)
    colours: dict[tuple[str, str, str], Any] = {}
    palette = colormaps["tab20"]  # up to 20 curves, none sharing a colour
    for (kind, det, odo, label), (_, _, rows) in results.items():
        if label not in ("chosen", "fused"):
            continue
        k = [r["passes"] for r in rows]
        colour = colours.setdefault((kind, det, odo), palette(len(colours) % 20))
        style = "-" if label == "fused" else ":"
        name = f"{det}, {kind}, {odo}" if label == "fused" else None
        ax_r.plot(k, [r["recall"] for r in rows], style, marker="o", color=colour, label=name)
        ax_f.plot(k, [r["false_per_km"] for r in rows], style, marker="o", color=colour)
    ax_r.plot([], [], "k-", label="fused (solid)")
    ax_r.plot([], [], "k:", label="votes, dev-chosen rule (dotted)")
    ax_r.axhline(TARGET_RECALL, color="0.5", lw=0.8, ls=":")
    ax_f.axhline(TARGET_FALSE, color="0.5", lw=0.8, ls=":")
    ax_r.set(xlabel="passes", ylabel="recall of defect positions (±2 m)", xticks=COUNTS,
             ylim=(0, 1.02))
    ax_f.set(xlabel="passes", ylabel="false locations per km", xticks=COUNTS, yscale="symlog")
    fig.legend(loc="outside right upper", fontsize=7)
    for ax in (ax_r, ax_f):
        ax.grid(alpha=0.3)
    return fig


if __name__ == "__main__":
    main()
