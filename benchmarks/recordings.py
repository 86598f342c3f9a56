"""Measure the recordings pipeline on one CPU core and write docs/results/recordings/recordings.md:

1. detection quality on a synthesised 10-minute run (attention model, default settings, trained on
   two other 10-minute runs): share of defects found within +-0.25 s, false events per minute;
2. real-time factor of `railwatch detect` (seconds of 2000 Hz six-channel recording scanned per
   second of wall time) on one core, for a 10- and a 60-minute recording, with peak memory;
3. onboard latency of one 2-s window (batch 1) with onnxruntime and with PyTorch, one thread, and
   of the streaming scorer taking 0.5-s blocks of raw samples.

Run: `make bench-recordings` (about 5 minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks.common import match, railwatch

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/recordings/recordings.md"
MINUTES = 5

def latency(fn, repeats: int = 300) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """Median and 99th percentile milliseconds of fn() after 20 warm-up calls."""
    for _ in range(20):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1e3), float(np.percentile(times, 99) * 1e3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default=PAGE)
    parser.add_argument("--work", default="runs/recordings", help="folder for the runs (kept)")
    args = parser.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    print(f"working in {work}", file=sys.stderr)

    for name, seed, minutes in (("train1.parquet", 1, 10), ("train2.parquet", 2, 10),
                                ("test.parquet", 0, 10), ("long.parquet", 3, 60)):
        if not (work / name).exists():
            railwatch("generate-run", "--minutes", str(minutes), "--seed", str(seed),
                      "--out", str(work / name))
    model = work / "model"
    fit_s = railwatch("train", "--detector", "aft-attention", "--recordings",
                         str(work / "train1.parquet"), str(work / "train2.parquet"), "--layout",
                         str(work / "train1.layout.toml"), "--out", str(model)).wall_s
    print(f"trained in {fit_s:.1f} s", file=sys.stderr)

    from railwatch.detection.pipeline import read_events

    rows = []
    for name, minutes in (("test.parquet", 10), ("long.parquet", 60)):
        events_path = work / f"{name}.events.csv"
        ran = railwatch("detect", "--model", str(model), "--recording", str(work / name),
                        "--out", str(events_path), one_core=True)
        wall, peak = ran.wall_s, ran.peak_mib
        events = read_events(events_path)
        found, false, channel = match(events, work / name.replace(".parquet", ".defects.csv"))
        rows.append((name, minutes, wall, minutes * 60 / wall, peak, len(events), found,
                     false / minutes, channel))
        print(rows[-1], file=sys.stderr)
    railwatch("detect", "--model", str(model), "--recording", str(work / "test.parquet"),
              "--out", str(work / "test.events.csv"), "--plot", str(work / "test.png"),
              "--truth", str(work / "test.defects.csv"))

    # The same run at the detector's own threshold (the spec's contamination quantile, 0.10)
    # instead of the recordings rule (GumbelNull): why train --recordings fits its own.
    # The model keeps only the event threshold, so the contamination quantile is taken again
    # from the training windows' instance scores, as the detector's own fit takes it.
    from railwatch.detection.pipeline import load_recording_model, training_windows
    from railwatch.recordings.readers import Recording
    from railwatch.scoring.thresholds import ContaminationQuantile

    own = load_recording_model(model)
    X = training_windows([Recording(work / n, own.layout) for n in ("train1.parquet",
                                                                     "train2.parquet")],
                         own.preparation)
    own_threshold = ContaminationQuantile(own.detector.config.contamination).fit(
        own.detector.score(X).instance)
    railwatch("detect", "--model", str(model), "--recording", str(work / "test.parquet"),
              "--out", str(work / "own.csv"), "--threshold", repr(own_threshold))
    own_found, own_false, _ = match(read_events(work / "own.csv"), work / "test.defects.csv")

    # Onboard latency, one thread.
    import torch

    torch.set_num_threads(1)
    from railwatch.deploy.onnx import export_onnx, load_onnx
    from railwatch.detection.pipeline import load_recording_model
    from railwatch.detection.stream import StreamingDetector
    from railwatch.recordings.readers import Recording

    export_onnx(model, work / "model.onnx")
    rm = load_recording_model(model)
    onnx = load_onnx(work / "model.onnx", threads=1)
    rec = Recording(work / "test.parquet", rm.layout).read()
    from railwatch.recordings.prepare import resample

    window = resample(rec.data[:4000], 1, 20)[None, :200]  # one 2-s window at 100 Hz
    lat_onnx = latency(lambda: onnx.score(window))
    lat_torch = latency(lambda: rm.detector.score(window))
    blocks = [rec.data[i:i + 1000] for i in range(0, 200_000, 1000)]  # 0.5-s raw blocks
    stream = StreamingDetector(onnx, rm.layout, rm.preparation, rm.threshold)
    it = iter(blocks)
    lat_stream = latency(lambda: stream.push(next(it)), repeats=150)

    from railwatch.machine import cpu_name
    from railwatch.report.pages import write_markdown

    lines = [
        "# Recordings: detection, real-time factor and onboard latency", "",
        f"`make bench-recordings` on {datetime.date.today()}: {cpu_name()}, "
        f"{len(os.sched_getaffinity(0))} cores; detect pinned to one core (`taskset -c 0`, "
        "OMP/MKL threads 1); torch and onnxruntime with 1 thread for latency.", "",
        "Model: `aft-attention` at default settings, trained with `railwatch train --recordings` "
        f"on two synthesised 10-minute runs (seeds 1, 2) in {fit_s:.0f} s (2 cores). Runs: "
        "`railwatch generate-run` (2000 Hz, six channels, Stage-5 signals, defects of the upper "
        "half of the benchmark's sizes, one every 10 s on average).", "",
        "| recording | minutes | detect wall (s) | real-time factor | peak memory (MiB) | events "
        "| defects found (±0.25 s) | false events / min | right channel |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, minutes, wall, rtf, peak, n_ev, found, false, channel in rows:
        lines.append(f"| {name} | {minutes} | {wall:.1f} | {rtf:.0f}× | {peak:.0f} | {n_ev} | "
                     f"{found:.0%} | {false:.2f} | {channel:.0%} |")
    lines += [
        "", "Wall time is the whole command: Python start-up, model load, reading Parquet, "
        "resampling 2000 -> 100 Hz, scoring every 2-s window every 0.5 s, events, CSV.", "",
        f"Event threshold: the recordings rule (`GumbelNull`, {own.threshold:.3g}) against the "
        f"detector's own contamination-0.10 threshold ({own_threshold:.3g}) on the "
        f"10-minute run: {rows[0][6]:.0%} vs {own_found:.0%} of defects found, "
        f"{rows[0][7]:.2f} vs {own_false / 10:.2f} false events per minute.", "",
        "| onboard latency, one thread | median (ms) | 99th percentile (ms) |", "|---|---|---|",
        f"| one 2-s window, onnxruntime | {lat_onnx[0]:.2f} | {lat_onnx[1]:.2f} |",
        f"| one 2-s window, PyTorch | {lat_torch[0]:.2f} | {lat_torch[1]:.2f} |",
        f"| streaming push of 0.5 s of raw 2000 Hz samples (resample, score, events), "
        f"onnxruntime | {lat_stream[0]:.2f} | {lat_stream[1]:.2f} |",
        "", "An event leaves the streaming scorer at most about 3.1 s of recording after the "
        "defect (window 2 s + hop 0.5 s + merge gap 0.5 s + filter delay 0.1 s), plus the "
        "computing latency above.", "",
    ]
    print(write_markdown(args.out, lines), end="")
    print(json.dumps({"work": str(work)}), file=sys.stderr)


if __name__ == "__main__":
    main()
