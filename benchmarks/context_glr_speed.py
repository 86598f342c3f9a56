"""context-glr's speed against its accuracy: the network's width, on six channels.

    python -m benchmarks context_glr_speed [WIDTHS]     # make bench-context-glr-speed

The speed targets of the noise-robust detector issue are: score 3,000 six-channel windows in
<= 2 s at batch 32 on 2 cores, fit 3,000 of them in <= 4 min, and <= 2 ms per 2-s window in
onnxruntime on one core, with ONNX scores equal to PyTorch's within 1e-3. The network is most of
the scoring cost, and its cost grows with the square of its width. Per width (default 16, 24, 32,
48, 64; every other setting at its default, 25 epochs), at standard sizes on stage 7 (six
channels; 3,000 training and 3,000 test windows drawn with seeds 2468 / 2469, not the benchmark's
seeds, so that nothing is chosen on a benchmark test set):

- fit seconds and instance ROC-AUC;
- scoring seconds of the 3,000 test windows at batch 32 (2 threads, median of 3), and the part of
  it that is the GLR scan (the rest is the network);
- onnxruntime on one thread: milliseconds per window (scoring 320 windows at batch 32, scan
  included, median of 3) and the largest score difference from PyTorch.

Writes docs/results/detectors/context-glr-speed.md and docs/results/detectors/context-glr-speed.png.
"""

from __future__ import annotations

import datetime
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from matplotlib.figure import Figure
from sklearn.metrics import roc_auc_score

from railwatch.deploy.onnx import export_onnx, load_onnx
from railwatch.detectors import create
from railwatch.evaluation.metrics import timed, timed_scores
from railwatch.machine import cpu_name
from railwatch.report.figures import save_figure
from railwatch.report.pages import write_markdown
from railwatch.synthetic import generate

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/detectors/context-glr-speed.md"
MINUTES = 15

STAGE, N_TRAIN, N_TEST, SEEDS = 7, 3000, 3000, (2468, 2469)
WIDTHS = (16, 24, 32, 48, 64)
ONNX_WINDOWS = 320
OUT = Path(__file__).resolve().parents[1] / "docs" / "results"


def measure(width: int, train: np.ndarray, test: np.ndarray, y: np.ndarray) -> dict[str, float]:
    det = create("context-glr", {"width": width, "progress": False})
    started = time.perf_counter()
    det.fit(train)
    fit_s = time.perf_counter() - started
    score_s, scores = timed_scores(det, test, repeats=3)
    raw = det.raw_outputs(det.normalized(test))
    scan_s, _ = timed(lambda: det.scores_from_raw(raw, extras=False), repeats=3)
    with tempfile.TemporaryDirectory() as tmp:
        export_onnx(det, Path(tmp) / "model.onnx")
        onnx = load_onnx(Path(tmp) / "model.onnx", threads=1)
        part = test[:ONNX_WINDOWS]
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            onnx_s, onnx_scores = timed_scores(onnx, part, repeats=3)
        finally:
            torch.set_num_threads(threads)
    reference = scores.channel[:ONNX_WINDOWS]
    return {
        "width": width, "fit_s": fit_s, "auc": float(roc_auc_score(y, scores.instance)),
        "score_s": score_s, "scan_s": scan_s,
        "onnx_ms": 1000.0 * onnx_s / ONNX_WINDOWS,
        "onnx_diff": float(np.abs(onnx_scores.channel - reference).max()),
        "parameters": sum(p.numel() for p in det.model_.parameters()),
    }


def main() -> None:
    widths = tuple(int(w) for w in sys.argv[1].split(",")) if len(sys.argv) > 1 else WIDTHS
    train, test = generate(STAGE, N_TRAIN, SEEDS[0]), generate(STAGE, N_TEST, SEEDS[1])
    rows = []
    for w in widths:
        rows.append(measure(w, train.X, test.X, test.y))
        r = rows[-1]
        print(f"width {w}: AUC {r['auc']:.3f}, fit {r['fit_s']:.0f} s, scoring "
              f"{r['score_s']:.2f} s (scan {r['scan_s']:.2f} s), onnxruntime "
              f"{r['onnx_ms']:.2f} ms/window", flush=True)
    lines = [
        "# context-glr: speed against accuracy, by network width", "",
        f"`python -m benchmarks context_glr_speed` (`make bench-context-glr-speed`), "
        f"{datetime.date.today().isoformat()}, {cpu_name()}, torch {torch.__version__} "
        f"({torch.get_num_threads()} threads), CPU only. Stage {STAGE} (six channels), "
        f"{N_TRAIN:,} training / {N_TEST:,} test windows (seeds {SEEDS[0]} / {SEEDS[1]}, not the "
        "benchmark's), every other setting at its default (25 epochs).", "",
        "| width | parameters | instance ROC-AUC | fit (s) | scoring 3,000 windows (s) | of it the "
        "GLR scan (s) | onnxruntime, 1 thread (ms / window) | ONNX − PyTorch (max abs) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['width']} | {r['parameters']:,} | {r['auc']:.3f} | {r['fit_s']:.0f} | "
                     f"{r['score_s']:.2f} | {r['scan_s']:.2f} | {r['onnx_ms']:.2f} | "
                     f"{r['onnx_diff']:.1e} |")
    lines += ["", "Targets: scoring ≤ 2 s, fit ≤ 240 s, onnxruntime ≤ 2 ms per window, ONNX within "
              "1e-3 of PyTorch.", "", "![AUC against scoring time](context-glr-speed.png)", ""]
    write_markdown(OUT / "context-glr-speed.md", lines)
    fig = Figure(figsize=(6, 4), layout="constrained")
    ax = fig.subplots()
    ax.plot([r["score_s"] for r in rows], [r["auc"] for r in rows], "o-")
    for r in rows:
        ax.annotate(f"width {r['width']}", (r["score_s"], r["auc"]), textcoords="offset points",
                    xytext=(5, -10), fontsize=8)
    ax.axvline(2.0, color="grey", ls=":", label="2-s target")
    ax.set_xlabel("scoring 3,000 six-channel windows, 2 cores (s)")
    ax.set_ylabel(f"instance ROC-AUC, stage {STAGE}")
    ax.set_title("context-glr: accuracy against scoring time")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    save_figure(fig, OUT / "context-glr-speed.png")
    print(f"wrote {OUT / 'context-glr-speed.md'}")


if __name__ == "__main__":
    main()
