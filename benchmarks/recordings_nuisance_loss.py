"""Where a detector loses on the nuisance runs: the nuisance signal, or the noise.

On the runs of `benchmarks/recordings_nuisance.py` (three seed trios each of stage-5-like and
stage-8-like runs with loud stretches; train on two, detect on the third), each detector is
trained and tested three times, on:

1. **the runs** as they are;
2. **the runs less their nuisance signal** (sinusoids, bursts, impulses: the run's components
   taken away), which leaves the white noise, whose level steps every 0.4-1.6 s and is 2-4x
   louder on the loud stretches, and the defects;
3. **those whitened by the true noise std**: the defects over unit white noise.

Beside them, the oracle (`railwatch.detection.oracle`) with the noise level known, estimated at
the recording's rate (2 kHz) and estimated after the resampling to 100 Hz (the same
greatest-of reference, in samples at 100 Hz). Each figure is the bound: the defects found at
<= 0.2 false events per minute by the best threshold on the test run. What 1 -> 2 gains is what
the nuisance signal costs the detector; 2 -> 3 what its handling of the noise costs.

Run: `python -m benchmarks recordings_nuisance_loss` (about 15 minutes on 2 cores for the
matched filter; `--detectors` picks others).
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
from pathlib import Path

import numpy as np

from benchmarks.common import command, match, railwatch
from benchmarks.recordings_nuisance import (
    FS,
    KINDS,
    RUN_MINUTES,
    TARGET_FALSE,
    TRIOS,
    best_at_false_rate,
    model_threshold,
)

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/recordings/recordings-nuisance-loss.md"
MINUTES = 15

INPUTS = {"runs": "the runs", "residual": "less the nuisance signal",
          "white": "less the nuisance, whitened by the true std"}


def run_file(work: Path, stage: int, seed: int, what: str) -> Path:
    """The test or training recording of ``stage``, ``seed`` as input ``what`` (:data:`INPUTS`),
    written once to ``work`` with its layout and defects."""
    from dataclasses import replace

    from railwatch.synthetic.run_files import save_run
    from railwatch.synthetic.runs import synthesize_run

    path = work / f"{what}-stage{stage}-seed{seed}.parquet"
    if path.exists():
        return path
    run = synthesize_run(RUN_MINUTES * 60, seed=seed, fs=FS, stage=stage, loud_stretches=True,
                         components=what != "runs")
    if what != "runs":
        assert run.nuisance is not None and run.noise_std is not None
        data = run.data - run.nuisance
        run = replace(run, data=data / run.noise_std if what == "white" else data)
    save_run(path, run)
    return path


def detector_bound(work: Path, det: str, stage: int, trio: tuple[int, int, int],
                   what: str) -> tuple[float, float]:
    """The detector trained on the trio's first two runs as ``what``: its bound on the third,
    and its false events per minute at its own threshold."""
    from railwatch.detection.pipeline import read_events

    a, b, c = (run_file(work, stage, s, what) for s in trio)
    model = work / f"model-{det}-{what}-stage{stage}-{trio[0]}{trio[1]}"
    if not model.exists():
        railwatch("train", "--detector", det, "--recordings", str(a), str(b), "--layout",
                  str(a.with_suffix(".layout.toml")), "--out", str(model))
    own = work / f"events-{model.name}.csv"
    railwatch("detect", "--model", str(model), "--recording", str(c), "--out", str(own))
    events = read_events(own)
    truth = c.with_suffix(".defects.csv")
    _, false, _ = match(events, truth)
    threshold = float(events[0]["threshold"]) if events else model_threshold(model)
    low = work / f"low-{model.name}.csv"
    railwatch("detect", "--model", str(model), "--recording", str(c), "--out", str(low),
              "--threshold", repr(threshold / 2))
    return best_at_false_rate(read_events(low), truth, TARGET_FALSE)[0], false / RUN_MINUTES


def oracle_bounds(work: Path, stage: int, seed: int) -> dict[str, float]:
    """The oracle's bound on the test run with the noise level known, estimated at the
    recording's rate, and estimated after the resampling (the same reference, at 100 Hz)."""
    from railwatch.detection.oracle import local_std, oracle_events, stream_events
    from railwatch.recordings.prepare import Preparation, resample
    from railwatch.synthetic.runs import synthesize_run

    truth = run_file(work, stage, seed, "runs").with_suffix(".defects.csv")
    run = synthesize_run(RUN_MINUTES * 60, seed=seed, fs=FS, stage=stage, loud_stretches=True,
                         components=True)
    out = {}
    for noise in ("known", "estimated"):
        events = [e.to_dict() for e in oracle_events(run, threshold=1.0, noise=noise)]
        out[noise] = best_at_false_rate(events, truth, TARGET_FALSE)[0]
    prep = Preparation()
    rate = prep.output_rate(FS)
    assert run.nuisance is not None
    e = resample((run.data - run.nuisance).astype(np.float64), *prep.ratio(FS))
    r = (e / local_std(e, rate)).astype(np.float32)
    at_rate = Preparation(rate=None)
    events = [ev.to_dict() for ev in stream_events(iter([r]), rate, at_rate, 1.0)]
    out["resampled"] = best_at_false_rate(events, truth, TARGET_FALSE)[0]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=PAGE)
    parser.add_argument("--work", default="runs/recordings-nuisance-loss",
                        help="folder for runs and models (kept)")
    parser.add_argument("--detectors", default="matched-filter")
    args = parser.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)

    def pct(x: float) -> str:
        return f"{x:.0%}"

    header = ("| runs | seeds | oracle: level known | level estimated at 2 kHz | after the "
              "resampling | " + " | ".join(f"`{d}`: {INPUTS[w]}" for d in
                                           args.detectors.split(",") for w in INPUTS) + " |")
    lines = [header, "|---|---|---|---|---|" + "---|" * (len(INPUTS) *
                                                          len(args.detectors.split(",")))]
    means: dict[str, list[float]] = {}
    for kind in KINDS:
        stage = int(KINDS[kind][1])
        for trio in TRIOS:
            orc = oracle_bounds(work, stage, trio[2])
            cells = [pct(orc[k]) for k in ("known", "estimated", "resampled")]
            for k in orc:
                means.setdefault(f"oracle {k}", []).append(orc[k])
            for det in args.detectors.split(","):
                for what in INPUTS:
                    bound, false = detector_bound(work, det, stage, trio, what)
                    means.setdefault(f"{det} {what}", []).append(bound)
                    cells.append(f"{pct(bound)} ({false:.1f})")
            lines.append(f"| {kind} | {'/'.join(map(str, trio))} | {' | '.join(cells)} |")
            print(lines[-1], file=sys.stderr, flush=True)
    lines.append("| **mean** | | " + " | ".join(pct(float(np.mean(v))) for v in means.values())
                 + " |")

    from railwatch.machine import cpu_name
    from railwatch.report.pages import write_markdown

    page = [
        "# Where a detector loses on the nuisance runs", "",
        f"`{command(__name__)}` on {datetime.date.today()}: {cpu_name()}, "
        f"{len(os.sched_getaffinity(0))} cores.", "",
        "The runs of [recordings-nuisance.md](recordings-nuisance.md) (train on two, detect on "
        "the third), given to each detector three ways: as they are; less their nuisance "
        "signal (sinusoids, bursts, impulses), which leaves white noise whose level steps every "
        "0.4-1.6 s and is 2-4x louder on loud stretches, and the defects; and that whitened by "
        "the true noise std. Beside them the oracle (`railwatch.detection.oracle`) with the "
        "noise level known, estimated at the recording's 2 kHz (a greatest-of reference, 0.3 s "
        "either side, 0.2 s away), and estimated the same way after the resampling to 100 Hz.",
        "",
        "Every figure is the **bound**: the defects found within +-0.25 s at <= 0.2 false events "
        "per minute by the best threshold on the test run. In brackets, the detector's false "
        "events per minute at its own threshold.", "",
        *lines, "",
        "Reading: the first step (the runs -> less the nuisance signal) is what the sinusoids, "
        "bursts and impulses cost the detector; the second (-> whitened) what its handling of "
        "a noise level that steps inside its windows costs. The oracle's columns say what an "
        "estimate of that level can cost at most, at each rate.", "",
    ]
    print(write_markdown(args.out, page), end="")


if __name__ == "__main__":
    main()
