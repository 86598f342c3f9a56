"""Recordings under the later stages' nuisance: train on two 10-minute runs, detect on a third,
for three seed trios each of stage-5-like and stage-8-like runs with loud stretches of track,
and write docs/results/recordings/recordings-nuisance.md (+ a figure of the worst trio's scores).

The runs come from `railwatch generate-run --stage {5,8} --loud-stretches` (HF bursts at rough
spots of the track and wheel-periodic impulses at stage 8, sections of 200-1500 m with 2-4x the
noise). Every trio counts, not the best one: the target (issue 29) is, in each, defects
within +-0.25 s found within 5 points of the oracle's bound, <= 0.2 false events per minute, the
loud track's false rate at most twice the quiet track's. `detect` runs on one core (taskset, one
thread): its own real-time factor (reading, resampling, scoring, events) and the whole
command's.

Beside each detector stands the **oracle** (`railwatch.detection.oracle`): it knows each run's
clean signal (sinusoids, bursts, impulses) and noise level, whitens the run with them and
streams it through `detect`'s pipeline with the window oracle's GLR test. Its threshold comes
from white noise (0.2 false events per minute), its bound from the test run as the detectors'
bound does. A second table runs it on the test runs of stages 5-8 with and without loud
stretches: what each nuisance costs what the data allow.

Run: `make bench-recordings-nuisance` (about 45 minutes on 2 Intel Xeon cores for the
three default detectors, 27 on AMD EPYC, 10 when their models are kept in `--work`).
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

from benchmarks.common import command, match, railwatch, real_time_factor
from railwatch.atomic import atomic_csv
from railwatch.detection.oracle import null_threshold, oracle_events
from railwatch.synthetic.runs import DEFECT_FIELDS, Variation, synthesize_run

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/recordings/recordings-nuisance.md"
MINUTES = 45

KINDS = {"stage 5": ["--stage", "5", "--loud-stretches"],
         "stage 8": ["--stage", "8", "--loud-stretches"]}
TRIOS = ((1, 2, 3), (4, 5, 6), (7, 8, 9))  # train, train, detect
RUN_MINUTES = 10  # each run's length
#: Issue targets, per trio: found within TARGET_GAP of the oracle's bound, at most TARGET_FALSE
#: false events per minute, loud track at most TARGET_LOUD times quiet track's false rate.
TARGET_GAP, TARGET_FALSE, TARGET_LOUD, TARGET_RTF = 0.05, 0.2, 2.0, 100.0
FS = 2000.0  # `generate-run`'s rate
#: Labels that train a registry detector with `train` flags (as in benchmarks/track_map.py).
TRAIN_FLAGS = {"matched-filter-wheel": ("matched-filter", ("--wheel-comb",))}


def oracle_row(work: Path, stage: int, loud: bool, seed: int,  # type: ignore[type-arg]
               threshold: float, noise: str = "known", variation: Variation | None = None,
               name: str = "") -> dict:
    """The oracle on the run of ``stage``, ``seed`` (remade with its components, its defects
    written to ``work``): its events above ``threshold`` (:func:`null_threshold`), its bound,
    and, with ``loud`` stretches, the split by loud and quiet track; ``noise``: known, or
    estimated from the residual (`railwatch.detection.oracle.local_std`); ``variation``: the
    run made differently (``name`` tells its files apart)."""
    run = synthesize_run(RUN_MINUTES * 60, seed=seed, fs=FS, stage=stage, loud_stretches=loud,
                         components=True, variation=variation)
    truth = work / f"oracle-{name}stage{stage}{'-loud' if loud else ''}-seed{seed}.defects.csv"
    atomic_csv(truth, DEFECT_FIELDS, run.defects)
    low = [e.to_dict() for e in oracle_events(run, threshold=1.0, noise=noise)]
    events = [e for e in low if e["score"] >= threshold]
    found, false, channel = match(events, truth)
    return {"detector": "oracle", "found": found, "false_min": false / RUN_MINUTES,
            "channel": channel, "events": len(events), "threshold": threshold,
            "bound": best_at_false_rate(low, truth, TARGET_FALSE), "fit_s": float("nan"),
            "rtf": float("nan"), "rtf_command": float("nan"),
            **(by_stretch(events, truth, stage, seed, variation) if loud else {})}


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


def by_stretch(events: list[dict], truth: Path, stage: int,  # type: ignore[type-arg]
               seed: int, variation: Variation | None = None) -> dict[str, float]:
    """Defects found and false events per minute inside the loud stretches and outside them
    (the stretches re-drawn from the run's seed and ``variation``: they are not in the
    recording)."""
    import csv

    fs = 200.0  # the stretches depend on the track position only, not on the rate
    loud = synthesize_run(RUN_MINUTES * 60, seed=seed, fs=fs, stage=stage, loud_stretches=True,
                          variation=variation)
    quiet = synthesize_run(RUN_MINUTES * 60, seed=seed, fs=fs, stage=stage, variation=variation)
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
    parser.add_argument("--detectors",
                        default="nuisance-glr,context-glr,aft-attention")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="config override passed to every 'train'")
    args = parser.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    from railwatch.detection.pipeline import read_events

    null = null_threshold(TARGET_FALSE, FS)
    null_est = null_threshold(TARGET_FALSE, FS, noise="estimated")
    ablation = {(stage, loud, noise, trio[2]): oracle_row(
        work, stage, loud, trio[2], null if noise == "known" else null_est, noise)
        for stage in (5, 6, 7, 8) for loud in (False, True) for noise in ("known", "estimated")
        for trio in TRIOS}
    rows = [{**ablation[(int(KINDS[kind][1]), True, "known", trio[2])], "kind": kind,
             "trio": trio} for kind in KINDS for trio in TRIOS]  # the oracle's rows: its runs
    oracle = {(r["kind"], r["trio"]): r for r in rows}
    print("oracle done", file=sys.stderr, flush=True)
    for det in [d for d in args.detectors.split(",") if d]:
        for kind in KINDS:
            for trio in TRIOS:
                a, b, c = (run_file(work, kind, s) for s in trio)
                model = work / f"model-{det}-{kind.replace(' ', '')}-{trio[0]}{trio[1]}"
                sets = [x for kv in args.set for x in ("--set", kv)]
                timed = model.with_name(model.name + ".fit_s")  # kept beside a kept model
                if not model.exists():
                    name, flags = TRAIN_FLAGS.get(det, (det, ()))
                    timed.write_text(repr(railwatch(
                        "train", "--detector", name, *flags, "--recordings", str(a), str(b),
                        "--layout", str(a.with_suffix(".layout.toml")), "--out", str(model),
                        *sets).wall_s))
                fit_s = float(timed.read_text()) if timed.exists() else float("nan")
                events_path = work / f"events-{model.name}-seed{trio[2]}.csv"
                ran = railwatch("detect", "--model", str(model), "--recording", str(c),
                                "--out", str(events_path), one_core=True, quiet=False,
                                capture=True)
                events = read_events(events_path)
                truth = c.with_suffix(".defects.csv")
                found, false, channel = match(events, truth)
                threshold = float(events[0]["threshold"]) if events else model_threshold(model)
                low_path = work / f"low-{events_path.name}"
                railwatch("detect", "--model", str(model), "--recording", str(c), "--out",
                          str(low_path), "--threshold", repr(threshold / 2))
                bound = best_at_false_rate(read_events(low_path), truth, TARGET_FALSE)
                split = by_stretch(events, truth, int(KINDS[kind][1]), trio[2])
                rows.append({"detector": det, "kind": kind, "trio": trio, "fit_s": fit_s,
                             "rtf": real_time_factor(ran.stderr),
                             "rtf_command": RUN_MINUTES * 60 / ran.wall_s, "found": found,
                             "false_min": false / RUN_MINUTES, "channel": channel,
                             "events": len(events), "model": model, "test": c,
                             "threshold": threshold, "bound": bound, **split})
                print(rows[-1], file=sys.stderr, flush=True)

    detected = [r for r in rows if r["detector"] != "oracle"]
    figure = Path(args.out).with_suffix(".png")
    if detected:
        worst = min(detected, key=lambda r: (r["detector"] != detected[0]["detector"],
                                             r["found"]))
        railwatch("detect", "--model", str(worst["model"]), "--recording", str(worst["test"]),
                  "--out", str(work / "worst.csv"), "--plot", str(figure),
                  "--truth", str(worst["test"].with_suffix(".defects.csv")))

    from railwatch.machine import cpu_name
    from railwatch.report.pages import write_markdown

    def pct(x: float) -> str:
        return "–" if np.isnan(x) else f"{x:.0%}"

    def met(r: dict) -> str:  # type: ignore[type-arg]
        if r["detector"] == "oracle":
            return "–"
        ceiling = oracle[(r["kind"], r["trio"])]["bound"][0]
        ok = (r["found"] >= ceiling - TARGET_GAP and r["false_min"] <= TARGET_FALSE
              and r["false_loud"] <= TARGET_LOUD * max(r["false_quiet"], 1.0 / RUN_MINUTES)
              and r["rtf"] >= TARGET_RTF)
        return "yes" if ok else "no"

    sets = f" with `--set {' --set '.join(args.set)}`" if args.set else ""
    flagged = [f"`{d}` is `{TRAIN_FLAGS[d][0]}` trained with `{' '.join(TRAIN_FLAGS[d][1])}`"
               for d in dict.fromkeys(r["detector"] for r in detected) if d in TRAIN_FLAGS]
    sets += f" ({'; '.join(flagged)})" if flagged else ""
    lines = [
        "# Recordings under the later stages' nuisance", "",
        (f"`{command(__name__)}`"
         if sys.argv[1:] else "`make bench-recordings-nuisance`")
        + f" on {datetime.date.today()}: {cpu_name()}, "
        f"{len(os.sched_getaffinity(0))} cores (training); `detect` pinned to one core "
        "(`taskset -c 0`, one thread). Its real-time factor is the one `detect` reports: "
        "reading, preparing and scoring the recording, not start-up and loading the model (a "
        "vehicle's detector runs for hours and starts once); beside it the whole command's, "
        "start-up included.", "",
        f"Each detector at default settings{sets}, trained with `railwatch train --recordings` on "
        "two 10-minute runs and detecting on a third, per seed trio (train, train, detect). Runs: "
        "`railwatch generate-run --stage 5|8 --loud-stretches` (stage 8: HF bursts at rough spots "
        "of the track, wheel-periodic impulses; both: sections of 200-1500 m with 2-4x the "
        "noise). A defect is found by an event whose peak lies within +-0.25 s of it. A "
        "model kept in the work folder is not trained again: its fit time is the one measured "
        "when it was trained (kept beside it).", "",
        "**The oracle** knows each run's clean signal (sinusoids, bursts, impulses) and noise "
        "level: it whitens the run with them and streams it through `detect`'s pipeline (the "
        "same resampling to 100 Hz, 2-s windows, merging into events), scored by the window "
        "oracle's GLR test (`railwatch.detection.oracle`). Its threshold is the score that "
        f"white noise streamed the same way crosses {TARGET_FALSE:g} times a minute "
        f"({null:.2f}): no training, no truth. Its bound is the ceiling of what the "
        "runs allow a detector at 100 Hz.", "",
        f"**Target** (every trio): defects found within {TARGET_GAP:.0%} of the oracle's bound "
        f"on the same run, at most {TARGET_FALSE:g} false events per minute, loud track at most "
        f"{TARGET_LOUD:g}x quiet track's false rate, `detect` >= {TARGET_RTF:g}x real time on "
        "one core.", "",
        "| detector | runs | seeds | defects found | false events / min | right channel | "
        "events | threshold | bound: found at <= 0.2 false/min (threshold) | "
        "found: quiet / loud track | false / min: quiet / loud track | fit (s) | "
        "real-time factor, 1 core: scanning / whole command | target met |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(rows, key=lambda r: r["detector"] != "oracle"):
        lines.append(
            f"| {r['detector']} | {r['kind']} | {'/'.join(map(str, r['trio']))} | "
            f"{r['found']:.0%} | {r['false_min']:.2f} | {pct(r['channel'])} | {r['events']} | "
            f"{r['threshold']:.3g} | {r['bound'][0]:.0%} ({r['bound'][1]:.3g}) | "
            f"{pct(r['found_quiet'])} / {pct(r['found_loud'])} | "
            f"{r['false_quiet']:.2f} / {r['false_loud']:.2f} | "
            + ("– | – | " if r["detector"] == "oracle" else
               f"{r['fit_s']:.0f} | {r['rtf']:.0f}× / {r['rtf_command']:.0f}× | ")
            + f"{met(r)} |")
    for det in dict.fromkeys(r["detector"] for r in detected):
        mine = [r for r in detected if r["detector"] == det]
        gap = max(oracle[(r["kind"], r["trio"])]["bound"][0] - r["found"] for r in mine)
        lines.append("")
        lines.append(
            f"`{det}`: worst trio {min(r['found'] for r in mine):.0%} found, "
            f"{max(r['false_min'] for r in mine):.2f} false events per minute at most, "
            f"{gap * 100:.0f} points below the oracle's bound at most, "
            f"median real-time factor {np.median([r['rtf'] for r in mine]):.0f}× (scanning).")
    lines += ["", "Quiet / loud track: the defects and false events on the rough sections "
              f"(about {np.mean([r['loud_share'] for r in rows]):.0%} of each run, 2-4x the "
              "noise) and off them; a threshold that holds when a stretch's noise level changes "
              "gives the same false-event rate on both.",
              "", "The bound column picks, per trio, the single threshold that finds the most "
              "defects with at most 0.2 false events per minute *on the test run itself*: what "
              "a perfect threshold rule could reach with these scores, not a result. The "
              "oracle's bound is the ceiling the target is measured against.", ""]
    seeds = "/".join(str(t[2]) for t in TRIOS)
    lines += ["## What each nuisance costs the oracle", "",
              "The oracle's bound (defects found at <= 0.2 false events per minute, threshold "
              "chosen on the run) on the test runs of each stage, without and with loud "
              "stretches. Every stage has the noise level that steps every 0.4-1.6 s; stage 6 "
              "draws the defect's channel by its kind's odds, stage 7 adds HF bursts, stage 8 "
              "wheel-periodic impulses. The oracle knows the bursts and impulses, so they cost "
              "it nothing; a loud stretch lowers a defect's signal-to-noise ratio, and that no "
              "detector can undo.", "",
              "The oracle that **estimates the noise level** knows the clean signal only: it "
              "whitens the residual by its root mean square over 0.3 s on either side of each "
              "sample, 0.2 s away, the greater side (a greatest-of CFAR; "
              "`railwatch.detection.oracle.local_std`), and its threshold comes from white "
              "noise whitened the same way "
              f"({null_est:.2f}). What it loses against the oracle is what not knowing the noise "
              "level costs; what a detector loses beyond it lies in the detector itself (its "
              "model of the clean signal, its own estimate of the level).", "",
              f"| stage | quiet track: bound (seeds {seeds}) | noise level estimated | "
              "loud stretches: bound | noise level estimated | loud stretches, the defects on "
              "them: found at the oracle's threshold |",
              "|---|---|---|---|---|---|"]

    def each(stage: int, loud: bool, noise: str, key: str) -> str:
        vals = [ablation[(stage, loud, noise, t[2])][key] for t in TRIOS]
        return " / ".join(pct(v[0] if isinstance(v, tuple) else v) for v in vals)

    for stage in (5, 6, 7, 8):
        lines.append(f"| {stage} | {each(stage, False, 'known', 'bound')} | "
                     f"{each(stage, False, 'estimated', 'bound')} | "
                     f"{each(stage, True, 'known', 'bound')} | "
                     f"{each(stage, True, 'estimated', 'bound')} | "
                     f"{each(stage, True, 'known', 'found_loud')} |")
    lines += [""]
    if detected:
        lines += [f"![scores of the worst trio]({figure.name})", "",
                  f"The figure: `{worst['detector']}` on {worst['test'].name} (its worst "
                  "trio).", ""]
    print(write_markdown(args.out, lines), end="")


if __name__ == "__main__":
    main()
