"""Measure every registered detector at its default size and write
docs/results/detectors/detectors.md:

1. stage-1 quality: fit on 2,000 windows (seed 0), instance ROC-AUC on 1,000 test windows (seed 1);
2. speed: fit seconds on 2,000 six-channel stage-5 windows, scoring seconds of 3,000 six-channel
   windows at batch 32 (after a warm-up batch, median of 3);
3. the attention model against the Anomaly Transformer at equal width, depth and heads.

Run: `make bench-detectors` (about 15-25 minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import datetime
import os
import statistics
import sys
import time

import torch

from railwatch.detectors import create, names
from railwatch.evaluation.metrics import auc_instance, score_seconds
from railwatch.machine import cpu_name
from railwatch.report.pages import write_markdown
from railwatch.synthetic import generate

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/detectors/detectors.md"
MINUTES = 25

#: Equal-size comparison of the attention model and the Anomaly Transformer (paper's Table II
#: claim: 502.5 s vs 673.5 s): the same width, heads, depth and feed-forward width.
PAIRS = 5
EQUAL_SIZE = {
    "aft-attention": {"d_model": 64, "n_heads": 4, "n_layers": 2, "d_ff": 64},
    "anomaly-transformer": {"d_model": 64, "n_heads": 4, "e_layers": 2, "d_ff": 64},
}


def context(d):  # type: ignore[no-untyped-def]
    return {"nuisance": d.nuisance, "noise_std": d.noise_std}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--detectors", default=",".join(names()))
    parser.add_argument("--out", default=PAGE)
    args = parser.parse_args()
    chosen = args.detectors.split(",")

    s1_train = generate(1, 2000, 0, components=True)
    s1_test = generate(1, 1000, 1, components=True)
    s5_train = generate(5, 2000, 0, components=True)
    s5_test = generate(5, 3000, 1, components=True)
    rows = []
    for name in chosen:
        det = create(name, {"progress": False})
        start = time.perf_counter()
        det.fit(s1_train.X, context(s1_train))
        fit1 = time.perf_counter() - start
        auc = auc_instance(s1_test.y, det.score(s1_test.X, context(s1_test)).instance)
        det6 = create(name, {"progress": False})
        start = time.perf_counter()
        det6.fit(s5_train.X, context(s5_train))
        fit6 = time.perf_counter() - start
        score6 = score_seconds(det6, s5_test.X, context(s5_test))
        rows.append((name, auc, fit1, fit6, score6))
        print(f"{name}: auc {auc:.3f}, fit1 {fit1:.1f}s, fit6 {fit6:.1f}s, "
              f"score6 {score6:.2f}s", file=sys.stderr)

    equal = []
    if "aft-attention" in chosen:
        # Alternating pairs in one process: this machine's speed drifts by up to 2x between
        # minutes, so the ratio is taken per pair and the median reported.
        small = generate(5, 256, 0)
        pair = [create(name, {"progress": False, "epochs": 1, **EQUAL_SIZE[name]}).fit(small.X)
                for name in ("aft-attention", "anomaly-transformer")]
        equal = [(score_seconds(pair[0], s5_test.X, repeats=1),
                  score_seconds(pair[1], s5_test.X, repeats=1)) for _ in range(PAIRS)]

    lines = [
        "# Detectors: stage-1 quality and speed at default sizes", "",
        f"`make bench-detectors` on {datetime.date.today()}: {cpu_name()}, "
        f"{len(os.sched_getaffinity(0))} cores, torch {torch.__version__} with "
        f"{torch.get_num_threads()} threads, device cpu.", "",
        "Stage-1 AUC: fit on `generate(1, 2000, seed=0)`, instance ROC-AUC on "
        "`generate(1, 1000, seed=1)`. Speed: fit on 2,000 stage-5 windows, scoring of 3,000 "
        "stage-5 windows (6 channels, T = 200) at batch 32 after a warm-up batch, median of 3.",
        "",
        "| detector | stage-1 AUC (instance) | fit 2,000 stage-1 windows (s) "
        "| fit 2,000 six-channel windows (s) | score 3,000 six-channel windows, batch 32 (s) |",
        "|---|---|---|---|---|",
    ]
    lines += [f"| {n} | {a:.3f} | {f1:.1f} | {f6:.1f} | {s6:.2f} |" for n, a, f1, f6, s6 in rows]
    if equal:
        ratios = sorted(at / aft for aft, at in equal)
        lines += ["", "## Equal size: attention model vs Anomaly Transformer", "",
                  "Both at d_model 64, 4 heads, 2 layers, feed-forward width 64, scoring 3,000 "
                  f"six-channel windows at batch 32 (after a warm-up batch), {PAIRS} alternating "
                  "pairs in one process:", "",
                  "| pair | aft-attention (s) | anomaly-transformer (s) | ratio |",
                  "|---|---|---|---|"]
        lines += [f"| {i + 1} | {aft:.2f} | {at:.2f} | {at / aft:.1f}× |"
                  for i, (aft, at) in enumerate(equal)]
        lines += ["", f"Speed-up, median of the pairs: **{statistics.median(ratios):.1f}×** "
                  f"(range {ratios[0]:.1f}–{ratios[-1]:.1f}×; the paper: 673.5 s / 502.5 s = "
                  "1.3×)."]
    print(write_markdown(args.out, lines), end="")


if __name__ == "__main__":
    main()
