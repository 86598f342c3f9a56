"""The matched filter's ridge (1e-6 before 2026-12-02, 0.1 since) on data it was not chosen on.

The ridge was chosen on the track map's development track (recordings of our run synthesiser,
resampled 2000 -> 100 Hz; docs/notes/2026-12-03-track-map-how-we-got-here.md, "Where the
per-pass loss came from"). Here:

1. **The benchmark's windows**, generated at 100 Hz with white noise (no resampling, no empty
   band): instance ROC-AUC per stage, 2,000 training windows (seed 0) and 2,000 test windows
   (seed 1).
2. **Windows made unlike ours**: recorded at 2048 Hz (not 2000) and resampled to 100 Hz by
   railwatch's resampler (25/512); the signal a chirp (5-30 Hz across the window, amplitude
   0.5-2.5) plus a slower sinusoid; the noise coloured (AR(1), coefficient 0.9) under a smooth
   envelope that varies 3-fold across the window (no steps); the defect a Hann-shaped bump of
   0.02-0.1 s (not a box) peaking at 3-8 times the local noise std, in half of the test
   windows. Trained on 2,000 defect-free windows, tested on 2,000: instance ROC-AUC and the
   share of defects that are the top score of their window (outside ±10 samples).

Run: `python -m benchmarks matched_filter_ridge` (about 5 minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import datetime
import re
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from benchmarks.common import command

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/detectors/matched-filter-ridge.md"
MINUTES = 5

RIDGES = (1e-6, 1e-2, 0.1, 1.0)
N_TRAIN, N_TEST = 2000, 2000
RAW_FS, UP, DOWN, STEPS = 2048.0, 25, 512, 200


def unlike_ours(n: int, seed: int, defects: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Windows (n, 200, 1) made as the module docstring's part 2 says; the labels and each
    defect's sample at 100 Hz (-1 without)."""
    from railwatch.recordings.prepare import Resampler

    rng = np.random.default_rng(seed)
    m = int(STEPS / 100.0 * RAW_FS) + 512  # raw samples, with a margin for the filter
    t = np.arange(m) / RAW_FS
    f0 = rng.uniform(5, 30, (n, 1))
    f1 = np.clip(f0 + rng.uniform(-10, 10, (n, 1)), 5, 30)
    phase = 2 * np.pi * (f0 * t + (f1 - f0) * t ** 2 / (2 * t[-1]))
    signal = (rng.uniform(0.5, 2.5, (n, 1)) * np.sin(phase + rng.uniform(0, 2 * np.pi, (n, 1)))
              + rng.uniform(0.2, 1.0, (n, 1)) * np.sin(2 * np.pi * rng.uniform(0.5, 3, (n, 1))
                                                        * t))
    white = rng.standard_normal((n, m))
    coloured = lfilter([np.sqrt(1 - 0.9 ** 2)], [1, -0.9], white, axis=1)  # unit variance
    level = rng.uniform(0.05, 0.5, (n, 1))
    envelope = level * np.exp(np.log(3.0) * np.sin(2 * np.pi * t / t[-1]
                                                   + rng.uniform(0, 2 * np.pi, (n, 1))) / 2)
    raw = signal + envelope * coloured
    y = np.zeros(n, dtype=int)
    at = np.full(n, -1)
    if defects:
        y = (rng.random(n) < 0.5).astype(int)
        for i in np.flatnonzero(y):
            width = int(rng.uniform(0.02, 0.1) * RAW_FS)
            start = int(rng.integers(int(0.3 * m), int(0.7 * m)))
            size = rng.uniform(3, 8) * envelope[i, start]
            raw[i, start:start + width] += rng.choice([-1, 1]) * size * np.hanning(width)
            at[i] = int((start + width / 2) * UP / DOWN)
    resampler = Resampler(UP, DOWN, n)  # every window a channel: one pass of the filter
    out = np.concatenate([resampler.push(raw.T.astype(np.float32)), resampler.flush()])
    return out[:STEPS].T[:, :, None].copy(), y, at


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(PAGE))
    args = parser.parse_args()
    from sklearn.metrics import roc_auc_score

    from railwatch.detectors import create
    from railwatch.machine import cpu_name
    from railwatch.report.pages import write_markdown
    from railwatch.synthetic import generate

    def fitted(ridge: float, X: np.ndarray):  # type: ignore[no-untyped-def]
        return create("matched-filter", {"progress": False, "ridge": ridge}).fit(X)

    bench = ["| stage | " + " | ".join(f"ridge {r:g}" for r in RIDGES) + " |",
             "|---|" + "---|" * len(RIDGES)]
    for stage in range(1, 9):
        train, test = generate(stage, N_TRAIN, 0), generate(stage, N_TEST, 1)
        aucs = [roc_auc_score(test.y, fitted(r, train.X).score(test.X).instance)
                for r in RIDGES]
        bench.append(f"| {stage} | " + " | ".join(f"{a:.3f}" for a in aucs) + " |")
        print(bench[-1], flush=True)

    train_x, _, _ = unlike_ours(N_TRAIN, 0, defects=False)
    test_x, y, at = unlike_ours(N_TEST, 1, defects=True)
    unlike = ["| ridge | instance ROC-AUC | defect the top of its window |", "|---|---|---|"]
    for r in RIDGES:
        channel = fitted(r, train_x).score(test_x).channel[:, :, 0]
        top = [channel[i, max(0, k - 2):k + 3].max()
               > np.delete(channel[i], np.r_[max(0, k - 10):k + 11]).max()
               for i, k in enumerate(at) if k >= 0]
        unlike.append(f"| {r:g} | {roc_auc_score(y, channel.max(axis=1)):.3f} | "
                      f"{np.mean(top):.0%} |")
        print(unlike[-1], flush=True)
    doc = __doc__.split("\n\n")
    on_benchmark, on_unlike = (" ".join(item.split())
                               for item in re.split(r"\n(?=\d\. )", doc[2]))
    lines = [
        "# The matched filter's ridge on data it was not chosen on",
        "",
        f"Command: `{command(__name__)}`, "
        f"{datetime.date.today().isoformat()}, {cpu_name()}, 2 cores. " + " ".join(doc[1].split()),
        "",
        on_benchmark,
        "",
        *bench,
        "",
        on_unlike,
        "",
        *unlike,
    ]
    print(write_markdown(args.out, lines))


if __name__ == "__main__":
    main()
