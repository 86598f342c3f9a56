"""Where context-glr loses against the oracle: its prediction of the normal signal or its noise
scale, each swapped for the generator's truth on the same trained network.

    python -m benchmarks context_glr_swap [STAGES]   # make bench-context-glr-swap (default 5,7)

Per stage, at the quick preset's sizes and context-glr's quick config (width 32, 8 epochs;
2,000 training windows of seed 0, 1,000 test windows of seed 1), the scan of the standardised
residual with every pairing of a prediction (learned / the true nuisance) and a noise scale
(learned / a change point estimated from the residual / the true noise std). The instance
ROC-AUC over all windows, over normal and spike windows ("spike") and over normal and
local-deviation windows ("box"). Also the prediction error against the true nuisance per sample
and averaged over 10 samples, each over the same for the noise. Writes
docs/results/detectors/context-glr-swap.md.
"""

from __future__ import annotations

import datetime
import sys
import time

import numpy as np
import torch
from numpy.typing import NDArray
from sklearn.metrics import roc_auc_score

from railwatch.detectors import create
from railwatch.machine import cpu_name
from railwatch.report.pages import write_markdown
from railwatch.scoring.glr import box_sums, cumulative
from railwatch.scoring.residual import ResidualGLR
from railwatch.synthetic import generate

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/detectors/context-glr-swap.md"
MINUTES = 3

N_TRAIN, N_TEST = 2000, 1000
CONFIG = {"epochs": 8, "width": 32, "progress": False}


def _centred(g: NDArray[np.float64]) -> NDArray[np.float64]:
    return g - np.median(g, axis=1, keepdims=True)


def _rms_ratio(err: NDArray[np.float64], noise: NDArray[np.float64], k: int) -> float:
    """rms of ``err``'s k-sample means over that of ``noise``'s."""
    def means(a: NDArray[np.float64]) -> NDArray[np.float64]:
        return box_sums(a, k, cumulative(a)) / k
    return float(np.sqrt((means(err) ** 2).mean() / (means(noise) ** 2).mean()))


def stage_rows(stage: int) -> tuple[list[str], str]:
    """The stage's table rows, and its row of prediction errors."""
    train, test = generate(stage, N_TRAIN, 0), generate(stage, N_TEST, 1, components=True)
    started = time.perf_counter()
    det = create("context-glr", CONFIG).fit(train.X)
    fit_s = time.perf_counter() - started
    s = det.score(test.X, extras=True)
    mean, std = det.stats_["input_mean"], det.stats_["input_std"]
    x = (test.X.astype(np.float64) - mean) / std
    nuisance = (test.nuisance - mean) / std
    noise_std = test.noise_std / std
    res = s.extras["residual"].astype(np.float64)
    near = s.extras["scale"] * det.stats_["z_spread_scale"]
    guard = s.extras["guard_scale"] * det.stats_["z_spread_guard_scale"]
    scan = ResidualGLR()
    true_res = x - nuisance
    pairs = {  # (prediction, scale): (spike residual, box residual)
        ("learned (context-glr)", "learned (near / guard band)"): (res / near, res / guard),
        ("learned", "the generator's true noise std"): (res / noise_std, res / noise_std),
        ("learned", "change point, from the residual"): (scan.standardized(res),) * 2,
        ("the generator's true nuisance", "learned"): (true_res / near, true_res / guard),
        ("true nuisance", "change point, from the residual"): (scan.standardized(true_res),) * 2,
        ("true nuisance", "true noise std (the oracle)"): (true_res / noise_std,) * 2,
    }
    y, kind = test.y, test.kind
    rows = []
    for (pred, scale), (g, g_box) in pairs.items():
        g, g_box = _centred(g), _centred(g_box)
        both = scan.scan(g, g_box).max(axis=(1, 2))
        spike = scan.scan(g, np.zeros_like(g)).max(axis=(1, 2))
        box = scan.scan(np.zeros_like(g), g_box).max(axis=(1, 2))
        rows.append(f"| {stage} | {pred} | {scale} | {roc_auc_score(y, both):.3f} | "
                    f"{roc_auc_score(y[kind != 2], spike[kind != 2]):.3f} | "
                    f"{roc_auc_score(y[kind != 1], box[kind != 1]):.3f} |")
        print(rows[-1], flush=True)
    err = true_res - res  # the prediction minus the true nuisance
    errors = (f"| {stage} | {_rms_ratio(err, true_res, 1):.2f} | "
              f"{_rms_ratio(err, true_res, 10):.2f} | {fit_s:.0f} |")
    return rows, errors


def main() -> None:
    stages = [int(v) for v in sys.argv[1].split(",")] if len(sys.argv) > 1 else [5, 7]
    table, errors = [], []
    for stage in stages:
        rows, error_row = stage_rows(stage)
        table += rows
        errors.append(error_row)
    lines = [
        "# context-glr: prediction or noise scale? (each swapped for the truth)",
        "",
        f"Command: `python -m benchmarks context_glr_swap {','.join(map(str, stages))}`, "
        f"{datetime.date.today().isoformat()}, {cpu_name()}, torch {torch.__version__}. "
        f"context-glr {CONFIG['width']} wide, {CONFIG['epochs']} epochs (the quick preset's), "
        f"{N_TRAIN:,} training windows (seed 0), {N_TEST:,} test windows (seed 1). "
        "Instance ROC-AUC of the same scan; spike: normal and spike windows only; box: normal "
        "and local-deviation windows only.",
        "",
        "| stage | prediction of the normal signal | noise scale | AUC | spike | box |",
        "|---|---|---|---|---|---|",
        *table,
        "",
        "Prediction error against the true nuisance, over the noise (rms per sample, and rms of "
        "10-sample means over the same for the noise):",
        "",
        "| stage | per sample | 10-sample means | fit (s) |",
        "|---|---|---|---|",
        *errors,
    ]
    print(write_markdown("docs/results/detectors/context-glr-swap.md", lines))


if __name__ == "__main__":
    main()
