"""Recordings under the later stages' nuisance: train on two 10-minute runs, detect on a third,
for three seed trios each of stage-5-like and stage-8-like runs with loud stretches of track,
and write docs/results/recordings/recordings-nuisance.md (+ a figure of the worst trio's scores).

The runs come from `railwatch generate-run --stage {5,8} --loud-stretches` (HF bursts at rough
spots of the track and wheel-periodic impulses at stage 8, sections of 200-1500 m with 2-4x the
noise). Every trio counts, not the best one: the issue's target is >= 90 % of defects within
+-0.25 s and <= 0.2 false events per minute in each. `detect` runs on one core (taskset, one
thread) and its whole command is timed (start-up, reading, resampling, scoring, events).

Run: `make bench-recordings-nuisance` (about 20 minutes on 2 cores for two detectors).
`--detectors matched-filter,matched-filter-wheel` measures the matched filter without and with
`train --wheel-comb` (about 5 minutes).
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
from pathlib import Path

import numpy as np

from benchmarks.common import command, match, railwatch

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/recordings/recordings-nuisance.md"
MINUTES = 20

KINDS = {"stage 5": ["--stage", "5", "--loud-stretches"],
         "stage 8": ["--stage", "8", "--loud-stretches"]}
TRIOS = ((1, 2, 3), (4, 5, 6), (7, 8, 9))  # train, train, detect
RUN_MINUTES = 10  # each run's length
TARGET_FOUND, TARGET_FALSE = 0.90, 0.2
#: Labels that train a registry detector with `train` flags (as in benchmarks/track_map.py).
TRAIN_FLAGS = {"matched-filter-wheel": ("matched-filter", ("--wheel-comb",))}


def run_file(work: Path, kind: str, seed: int) -> Path:
    path = work / f"{kind.replace(' ', '')}-seed{seed}.parquet"
    if not path.exists():
        railwatch("generate-run", "--minutes", str(RUN_MINUTES), "--seed", str(seed), *KINDS[kind],
                  "--out", str(path))
    return path


def model_threshold(model: Path) -> float:
    """The event threshold a recordings model was trained with (when it gave no event)."""
    from railwatch.detection.pipeline import load_recording_model

    return load_recording_model(model).threshold


def best_at_false_rate(events: list[dict], truth: Path,  # type: ignore[type-arg]
                       per_min: float) -> tuple[float, float]:
    """The most defects found by any one threshold with at most ``per_min`` false events per
    minute, and that threshold, from events detected at a lower threshold (an event at a
    higher one is approximated by the events whose peak score reaches it). Chosen on the test
    run itself: an upper bound on what a threshold rule could do, not a result."""
    best = (0.0, float("inf"))
    for t in sorted({float(e["score"]) for e in events}):
        kept = [e for e in events if float(e["score"]) >= t]
        found, false, _ = match(kept, truth)
        if false / RUN_MINUTES <= per_min and found > best[0]:
            best = (found, t)
    return best


def by_stretch(events: list[dict], truth: Path, kind: str,  # type: ignore[type-arg]
               seed: int) -> dict[str, float]:
    """Defects found and false events per minute inside the loud stretches and outside them
    (the stretches re-drawn from the run's seed: they are not in the recording)."""
    import csv

    from railwatch.synthetic.runs import synthesize_run

    fs = 200.0  # the stretches depend on the track position only, not on the rate
    stage = int(KINDS[kind][1])
    loud = synthesize_run(RUN_MINUTES * 60, seed=seed, fs=fs, stage=stage, loud_stretches=True)
    quiet = synthesize_run(RUN_MINUTES * 60, seed=seed, fs=fs, stage=stage)
    # white noise differs only on rough sections; bursts, impulses and defects cancel
    is_loud = np.abs(loud.data - quiet.data).max(axis=1) > 0

    def at(t: float) -> bool:
        return bool(is_loud[min(int(t * fs), len(is_loud) - 1)])

    with open(truth, newline="") as fh:
        centers = np.array([float(r["center_s"]) for r in csv.DictReader(fh)])
    peaks = np.array([float(e["peak_s"]) for e in events])
    out = {}
    for name, want in (("loud", True), ("quiet", False)):
        share = float(np.mean(is_loud == want))
        mine = [c for c in centers if at(c) == want]
        found = [bool(len(peaks)) and np.any(np.abs(peaks - c) <= 0.25) for c in mine]
        false = [p for p in peaks if at(p) == want and not np.any(np.abs(centers - p) <= 0.25)]
        out[f"found_{name}"] = float(np.mean(found)) if found else float("nan")
        out[f"false_{name}"] = len(false) / (RUN_MINUTES * share) if share else float("nan")
    out["loud_share"] = float(np.mean(is_loud))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default=PAGE)
    parser.add_argument("--work", default="runs/recordings-nuisance",
                        help="folder for runs and models (kept)")
    parser.add_argument("--detectors", default="context-glr,aft-attention")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="config override passed to every 'train'")
    args = parser.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    from railwatch.detection.pipeline import read_events

    rows = []
    for det in args.detectors.split(","):
        for kind in KINDS:
            for trio in TRIOS:
                a, b, c = (run_file(work, kind, s) for s in trio)
                model = work / f"model-{det}-{kind.replace(' ', '')}-{trio[0]}{trio[1]}"
                sets = [x for kv in args.set for x in ("--set", kv)]
                fit_s = float("nan")
                if not model.exists():
                    name, flags = TRAIN_FLAGS.get(det, (det, ()))
                    fit_s = railwatch("train", "--detector", name, *flags, "--recordings",
                                      str(a), str(b), "--layout",
                                      str(a.with_suffix(".layout.toml")), "--out",
                                      str(model), *sets).wall_s
                events_path = work / f"events-{model.name}-seed{trio[2]}.csv"
                wall = railwatch("detect", "--model", str(model), "--recording", str(c),
                                 "--out", str(events_path), one_core=True).wall_s
                events = read_events(events_path)
                truth = c.with_suffix(".defects.csv")
                found, false, channel = match(events, truth)
                threshold = float(events[0]["threshold"]) if events else model_threshold(model)
                low_path = work / f"low-{events_path.name}"
                railwatch("detect", "--model", str(model), "--recording", str(c), "--out",
                          str(low_path), "--threshold", repr(threshold / 2))
                bound = best_at_false_rate(read_events(low_path), truth, TARGET_FALSE)
                split = by_stretch(events, truth, kind, trio[2])
                rows.append({"detector": det, "kind": kind, "trio": trio, "fit_s": fit_s,
                             "rtf": RUN_MINUTES * 60 / wall, "found": found,
                             "false_min": false / RUN_MINUTES, "channel": channel,
                             "events": len(events), "model": model, "test": c,
                             "threshold": threshold, "bound": bound, **split})
                print(rows[-1], file=sys.stderr, flush=True)

    worst = min(rows, key=lambda r: (r["detector"] != rows[0]["detector"], r["found"]))
    figure = Path(args.out).with_suffix(".png")
    railwatch("detect", "--model", str(worst["model"]), "--recording", str(worst["test"]),
              "--out", str(work / "worst.csv"), "--plot", str(figure),
              "--truth", str(worst["test"].with_suffix(".defects.csv")))

    from railwatch.machine import cpu_name
    from railwatch.report.pages import write_markdown

    sets = f" with `--set {' --set '.join(args.set)}`" if args.set else ""
    lines = [
        "# Recordings under the later stages' nuisance", "",
        (f"`{command(__name__)}`"
         if sys.argv[1:] else "`make bench-recordings-nuisance`")
        + f" on {datetime.date.today()}: {cpu_name()}, "
        f"{len(os.sched_getaffinity(0))} cores (training); `detect` pinned to one core "
        "(`taskset -c 0`, one thread), whole command timed.", "",
        f"Each detector at default settings{sets}, trained with `railwatch train --recordings` on "
        "two 10-minute runs and detecting on a third, per seed trio (train, train, detect). Runs: "
        "`railwatch generate-run --stage 5|8 --loud-stretches` (stage 8: HF bursts at rough spots "
        "of the track, wheel-periodic impulses; both: sections of 200-1500 m with 2-4x the "
        "noise). Target (every trio): >= 90 % of defects within +-0.25 s, <= 0.2 false events "
        "per minute, `detect` >= 100x real time on one core.", "",
        "| detector | runs | seeds | defects found | false events / min | right channel | "
        "events | threshold | bound: found at <= 0.2 false/min (threshold) | "
        "found: quiet / loud track | false / min: quiet / loud track | fit (s) | "
        "real-time factor, 1 core | target met |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    def pct(x: float) -> str:
        return "–" if np.isnan(x) else f"{x:.0%}"

    for r in rows:
        met = (r["found"] >= TARGET_FOUND and r["false_min"] <= TARGET_FALSE
               and r["rtf"] >= 100)
        lines.append(
            f"| {r['detector']} | {r['kind']} | {'/'.join(map(str, r['trio']))} | "
            f"{r['found']:.0%} | {r['false_min']:.2f} | {pct(r['channel'])} | {r['events']} | "
            f"{r['threshold']:.3g} | {r['bound'][0]:.0%} ({r['bound'][1]:.3g}) | "
            f"{pct(r['found_quiet'])} / {pct(r['found_loud'])} | "
            f"{r['false_quiet']:.2f} / {r['false_loud']:.2f} | "
            f"{r['fit_s']:.0f} | {r['rtf']:.0f}× | {'yes' if met else 'no'} |")
    for det in dict.fromkeys(r["detector"] for r in rows):
        mine = [r for r in rows if r["detector"] == det]
        lines.append("")
        lines.append(
            f"`{det}`: worst trio {min(r['found'] for r in mine):.0%} found, "
            f"{max(r['false_min'] for r in mine):.2f} false events per minute at most, "
            f"median real-time factor {np.median([r['rtf'] for r in mine]):.0f}×.")
    lines += ["", "Quiet / loud track: the defects and false events on the rough sections "
              f"(about {np.mean([r['loud_share'] for r in rows]):.0%} of each run, 2-4x the "
              "noise) and off them; a threshold that holds when a stretch's noise level changes "
              "gives the same false-event rate on both.",
              "", "The bound column picks, per trio, the single threshold that finds the most "
              "defects with at most 0.2 false events per minute *on the test run itself*: what "
              "a perfect threshold rule could reach with these scores, not a result.",
              "", f"![scores of the worst trio]({figure.name})", "",
              f"The figure: `{worst['detector']}` on {worst['test'].name} (its worst trio).", ""]
    print(write_markdown(args.out, lines), end="")


if __name__ == "__main__":
    main()
