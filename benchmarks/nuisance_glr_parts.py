"""What each part of nuisance-glr recovers on the nuisance runs, stage by stage, beside the
oracle: the ablation table of `docs/nuisance-glr.md`.

On the runs of `benchmarks/recordings_nuisance.py` (10-minute runs with loud stretches; train on
two, detect on the third, seed trios 1/2/3, 4/5/6, 7/8/9) of stages 5, 6, 7 and 8, six
detectors are trained and streamed through `detect`'s pipeline in-process:

1. the matched filter (a robust linear predictor whitens the vibration; its noise level has
   one change point per window);
2. nuisance-glr's harmonic model alone, with a noise level that changes at most once per
   window (trained without the floor, as on windows that were never resampled; no burst
   model, no synchronous level, no edge guard);
3. + the recording's noise floor;
4. + the burst model;
5. + the impulses' synchronous level;
6. + each window's first and last 20 steps left to the windows that overlap them in the stream
   (``edge_guard``): nuisance-glr as it is;
7. the oracle (`railwatch.detection.oracle`): the run's clean signal and noise level known.

Each figure is the bound: defects found at <= 0.2 false events per minute by the best threshold
chosen on the test run. Stage 6 draws the defect's channel by its kind's odds; 7 adds HF bursts;
8 adds wheel-periodic impulses; every stage has a noise level that steps every 0.4-1.6 s and the
loud stretches.

Run: `python -m benchmarks nuisance_glr_parts` (about 8 minutes on 2 cores, 12 when it makes the
runs, which it shares with `make bench-recordings-nuisance` in the same `--work`); `--held-out --out
docs/results/recordings/nuisance-glr-parts-held-out.md` on seed trios 11-19, never looked at
while nuisance-glr's settings were chosen; `--made-differently --out
docs/results/recordings/nuisance-glr-made-differently.md` (about 15 minutes): the oracle, the
matched filter and nuisance-glr at stages 5 and 8 on runs made unlike the development runs
(:data:`MADE_DIFFERENTLY`), seed trios 21-29.
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
from pathlib import Path

import numpy as np

from benchmarks.common import command, match
from benchmarks.recordings_nuisance import (
    RUN_MINUTES,
    TARGET_FALSE,
    TRIOS,
    best_at_false_rate,
    by_stretch,
    oracle_row,
)
from railwatch.synthetic.runs import Variation

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/recordings/nuisance-glr-parts.md"
MINUTES = 12

STAGES = (5, 6, 7, 8)
#: Seed trios never looked at while nuisance-glr's settings were chosen (on TRIOS' runs):
#: `--held-out` measures on them.
HELD_OUT = ((11, 12, 13), (14, 15, 16), (17, 18, 19))
#: nuisance-glr without its burst model, synchronous level and edge guard
BARE = {"bursts": False, "period_guard": 0.0, "edge_guard": 0}
#: name -> (registry detector, trained with the noise floor, settings)
VARIANTS: dict[str, tuple[str, bool, dict[str, object]]] = {
    "matched filter": ("matched-filter", False, {}),
    "harmonic model, level with one change per window": ("nuisance-glr", False, BARE),
    "+ noise floor": ("nuisance-glr", True, BARE),
    "+ burst model": ("nuisance-glr", True, {"period_guard": 0.0, "edge_guard": 0}),
    "+ impulses' synchronous level": ("nuisance-glr", True, {"edge_guard": 0}),
    "+ windows' edges left to their neighbours (nuisance-glr)": ("nuisance-glr", True, {}),
}
#: `--made-differently`: runs made unlike the development runs (railwatch.synthetic.runs.
#: Variation), on seed trios never used before, at stages 5 and 8; "" is the runs as developed.
MADE_DIFFERENTLY: dict[str, tuple[str, Variation]] = {  # what -> (file prefix, how)
    "": ("", Variation()),
    "speed: knots every 20 s, 5-35 m/s, up to 1.5 m/s² (30 s, 15-30 m/s, 0.5 m/s²)": (
        "speed20s-", Variation(speed_knot_s=20.0, speed_range=(5.0, 35.0))),
    "noise: the level ramps from knot to knot (steps)": ("ramps-", Variation(noise_ramps=True)),
    "vibration: 2nd and 3rd harmonics at 0.5 and 0.25 (a sinusoid)": (
        "harmonics-", Variation(harmonics=(0.5, 0.25))),
    "deviations: triangles (boxes)": ("triangles-", Variation(deviation_shape="triangle")),
    "deviations: half-sines (boxes)": ("halfsines-", Variation(deviation_shape="half-sine")),
}
MADE_TRIOS = ((21, 22, 23), (24, 25, 26), (27, 28, 29))
MADE_STAGES = (5, 8)


def run_path(work: Path, stage: int, seed: int, made: str = "") -> Path:
    """The run of ``stage`` and ``seed`` with loud stretches (as `generate-run --stage S
    --loud-stretches` names them in recordings_nuisance), made differently as ``made`` says
    (:data:`MADE_DIFFERENTLY`; "": as developed), written once."""
    from railwatch.synthetic.run_files import write_run

    prefix, variation = MADE_DIFFERENTLY[made]
    path = work / f"{prefix}stage{stage}-seed{seed}.parquet"
    if not path.exists():
        write_run(path, RUN_MINUTES, seed=seed, stage=stage, loud_stretches=True,
                  variation=variation)
    return path


def variant_row(work: Path, stage: int, trio: tuple[int, int, int], variant: str,
                made: str = "") -> dict:  # type: ignore[type-arg]
    """One detector trained on the trio's first two runs, streamed over the third: its bound,
    and at its own event threshold the defects found and the false rates on and off the loud
    stretches; the runs made as ``made`` says."""
    from railwatch.detection.pipeline import (
        EVENTS_PER_MINUTE,
        detect,
        event_threshold,
        training_set,
    )
    from railwatch.detectors import create
    from railwatch.recordings.layout import load_layout
    from railwatch.recordings.prepare import Preparation
    from railwatch.recordings.readers import Recording

    name, floor, settings = VARIANTS[variant]
    a, b, c = (run_path(work, stage, s, made) for s in trio)
    layout = load_layout(a.with_suffix(".layout.toml"))
    prep = Preparation()
    X, context = training_set([Recording(p, layout) for p in (a, b)], prep, floor=floor)
    det = create(name, {"progress": False, **settings}).fit(X, context)
    threshold = det.set_threshold(event_threshold(prep, EVENTS_PER_MINUTE))
    low = [e.to_dict() for e in detect(det, Recording(c, layout), prep, threshold / 2).events]
    truth = c.with_suffix(".defects.csv")
    events = [e for e in low if e["score"] > threshold]
    found, false, _ = match(events, truth)
    return {"bound": best_at_false_rate(low, truth, TARGET_FALSE)[0], "found": found,
            "false_min": false / RUN_MINUTES,
            **by_stretch(events, truth, stage, trio[2], MADE_DIFFERENTLY[made][1])}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default=PAGE)
    parser.add_argument("--work", default="runs/recordings-nuisance",
                        help="folder of the runs (shared with recordings_nuisance; kept)")
    parser.add_argument("--held-out", action="store_true",
                        help="the held-out seed trios 11-19 instead of the development trios 1-9")
    parser.add_argument("--made-differently", action="store_true",
                        help="the oracle, the matched filter and nuisance-glr on runs made unlike "
                        "the development runs (seed trios 21-29, stages 5 and 8; --out "
                        "docs/results/recordings/nuisance-glr-made-differently.md)")
    args = parser.parse_args()
    if args.made_differently:
        return made_differently(Path(args.work), Path(args.out))
    trios = HELD_OUT if args.held_out else TRIOS
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    from railwatch.detection.oracle import null_threshold

    null = null_threshold(TARGET_FALSE, 2000.0)
    rows: dict[tuple[int, str], list[dict]] = {}  # type: ignore[type-arg]
    for stage in STAGES:
        for trio in trios:
            run_path(work, stage, trio[2])
            rows.setdefault((stage, "oracle"), []).append(
                oracle_row(work, stage, True, trio[2], null))
            for variant in VARIANTS:
                rows.setdefault((stage, variant), []).append(variant_row(work, stage, trio,
                                                                         variant))
                print(stage, trio, variant, rows[(stage, variant)][-1], file=sys.stderr,
                      flush=True)

    from railwatch.machine import cpu_name
    from railwatch.report.pages import write_markdown

    def bounds(stage: int, variant: str) -> str:
        vals = [r["bound"][0] if isinstance(r["bound"], tuple) else r["bound"]
                for r in rows[(stage, variant)]]
        return " / ".join(f"{v:.0%}" for v in vals) + f" (mean {np.mean(vals):.0%})"

    names = ["oracle", *VARIANTS]
    lines = [
        "# nuisance-glr, part by part", "",
        f"`{command(__name__)}` on {datetime.date.today()}: {cpu_name()}, "
        f"{len(os.sched_getaffinity(0))} cores.", "",
        "Runs of 10 minutes at 2 kHz with loud stretches (`railwatch generate-run --stage S "
        "--loud-stretches`), resampled to 100 Hz by `detect`'s pipeline; each detector trained "
        "on two runs and streamed over a third, per seed trio "
        f"({', '.join('/'.join(map(str, t)) for t in trios)}: train, train, detect; "
        + ("held-out seeds, never looked at while its settings were chosen" if args.held_out
           else "the development seeds, on which its settings were chosen") + "). "
        "Figure: the bound, defects found at <= 0.2 false events per minute by the best "
        "threshold chosen on the test run (per trio, then the mean). The oracle knows the "
        "run's clean signal and noise level (`railwatch.detection.oracle`).", "",
        "| stage | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for stage in STAGES:
        lines.append(f"| {stage} | " + " | ".join(bounds(stage, v) for v in names) + " |")
    from railwatch.detection.pipeline import EVENTS_PER_MINUTE

    default = list(VARIANTS)[-1]
    lines += ["", f"At its own event threshold ({EVENTS_PER_MINUTE:g} windows per minute of the "
              f"training runs' null, `railwatch train`'s default), `{default}`:", "",
              "| stage | defects found (per trio) | false events / min | "
              "false / min, quiet / loud track (per trio) |",
              "|---|---|---|---|"]
    for stage in STAGES:
        mine = rows[(stage, default)]
        found = " / ".join(f"{r['found']:.0%}" for r in mine)
        false = " / ".join(f"{r['false_min']:.1f}" for r in mine)
        split = ", ".join(f"{r['false_quiet']:.1f} / {r['false_loud']:.1f}" for r in mine)
        lines.append(f"| {stage} | {found} | {false} | {split} |")
    lines += ["", "Stages 5 and 6 carry the vibration and the stepping noise level; 7 adds "
              "bursts of rough track, 8 the wheel's impulses (`docs/nuisance-glr.md`).", ""]
    print(write_markdown(args.out, lines), end="")


def made_differently(work: Path, out: Path) -> None:
    """`--made-differently`: each way of making the runs differently, at stages 5 and 8, on seed
    trios never used before; the oracle, the matched filter and nuisance-glr."""
    from railwatch.detection.oracle import null_threshold
    from railwatch.machine import cpu_name
    from railwatch.report.pages import write_markdown

    work.mkdir(parents=True, exist_ok=True)
    null = null_threshold(TARGET_FALSE, 2000.0)
    ng = list(VARIANTS)[-1]
    detectors = ("oracle", "matched filter", ng)
    rows: dict[tuple[int, str, str], list[dict]] = {}  # type: ignore[type-arg]
    for stage in MADE_STAGES:
        for made, (prefix, variation) in MADE_DIFFERENTLY.items():
            for trio in MADE_TRIOS:
                run_path(work, stage, trio[2], made)
                rows.setdefault((stage, made, "oracle"), []).append(oracle_row(
                    work, stage, True, trio[2], null, variation=variation, name=prefix))
                for variant in detectors[1:]:
                    rows.setdefault((stage, made, variant), []).append(
                        variant_row(work, stage, trio, variant, made))
                print(stage, made or "as developed", trio, {d: rows[(stage, made, d)][-1]["bound"]
                                                            for d in detectors},
                      file=sys.stderr, flush=True)

    def bound(r: dict) -> float:  # type: ignore[type-arg]
        return float(r["bound"][0] if isinstance(r["bound"], tuple) else r["bound"])

    lines = [
        "# nuisance-glr on runs made differently", "",
        f"`{command(__name__)}` on {datetime.date.today()}: {cpu_name()}, "
        f"{len(os.sched_getaffinity(0))} cores.", "",
        "Runs of 10 minutes at 2 kHz with loud stretches, made unlike the runs nuisance-glr was "
        "developed on (`railwatch.synthetic.runs.Variation`; what the development runs have in "
        "brackets), on seed trios never used before "
        f"({', '.join('/'.join(map(str, t)) for t in MADE_TRIOS)}: train, train, detect). "
        "Every detector with its defaults, as in the part-by-part page. Figure: the bound, "
        "defects found at <= 0.2 false events per minute by the best threshold chosen on the "
        "test run, the mean of the three trios (each trio's in brackets). The last column: "
        "nuisance-glr at its own event threshold, false events per minute on quiet / loud "
        "track (each trio).", "",
        "| stage | runs made | oracle | matched filter | nuisance-glr | nuisance-glr's "
        "false / min, quiet / loud |",
        "|---|---|---|---|---|---|"]
    for stage in MADE_STAGES:
        for made in MADE_DIFFERENTLY:
            cells = []
            for d in detectors:
                vals = [bound(r) for r in rows[(stage, made, d)]]
                cells.append(f"{np.mean(vals):.0%} ({' / '.join(f'{v:.0%}' for v in vals)})")
            split = ", ".join(f"{r['false_quiet']:.1f} / {r['false_loud']:.1f}"
                              for r in rows[(stage, made, ng)])
            lines.append(f"| {stage} | {made or 'as developed'} | " + " | ".join(cells)
                         + f" | {split} |")
    print(write_markdown(out, lines), end="")


if __name__ == "__main__":
    main()
