"""Where the loss from stage 4 on comes from: the scoring or the model's prediction.

    python -m benchmarks residual_glr            # make bench-residual-glr

Per stage, at the quick preset's sizes (2,000 training and 1,000 test windows, seeds 0 / 1),
instance ROC-AUC of the spike/box GLR (railwatch.scoring.residual.ResidualGLR) on:

- the true residual (X − the generator's nuisance) divided by the true noise std: the oracle;
- the true residual with the noise scale *estimated* (one change point per window and channel):
  what the scale estimate costs;
- the CNN autoencoder's residual (reconstruction − input), scale estimated: what the GLR scoring
  gives a learned model, next to the same trained model's paper-faithful score.

The gap between the second and the last column is the model's prediction of the normal signal;
between the first two, the noise-scale estimate. Writes docs/results/detectors/residual-glr.md.
"""

from __future__ import annotations

import datetime
import time

import numpy as np
import torch
from sklearn.metrics import roc_auc_score

from railwatch.detectors import create
from railwatch.machine import cpu_name
from railwatch.report.pages import write_markdown
from railwatch.scoring.glr import families, scan
from railwatch.scoring.residual import ResidualGLR, null_counts
from railwatch.synthetic import generate

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/detectors/residual-glr.md"
MINUTES = 3

STAGES = range(1, 9)
N_TRAIN, N_TEST, EPOCHS = 2000, 1000, 8


def instance_auc(y: np.ndarray, channel: np.ndarray) -> float:
    return float(roc_auc_score(y, channel.max(axis=(1, 2))))


def main() -> None:
    glr = ResidualGLR()
    fams = families(glr.min_box, glr.max_box)
    norms = [[np.sqrt(L) for L in fam] for fam in fams]
    rows = ["| stage | oracle: true residual, true scale | true residual, estimated scale | "
            "cnn-ae (paper score) | cnn-ae residual + GLR | cnn-ae fit (s) |",
            "|---|---|---|---|---|---|"]
    for stage in STAGES:
        train = generate(stage, N_TRAIN, 0, components=True)
        test = generate(stage, N_TEST, 1, components=True)
        true_residual = test.X.astype(np.float64) - test.nuisance
        counts = np.array(null_counts(test.X.shape[1], fams, glr.null_windows, glr.alpha,
                                       glr.seed))
        oracle = instance_auc(test.y, scan(true_residual / test.noise_std, fams, norms, counts))
        estimated = instance_auc(test.y, glr.channel_scores(true_residual))
        started = time.perf_counter()
        det = create("cnn-ae", {"epochs": EPOCHS, "progress": False}).fit(train.X)
        fit_s = time.perf_counter() - started
        paper = float(roc_auc_score(test.y, det.score(test.X).instance))
        x = torch.from_numpy(det.normalized(test.X.astype(np.float32)))
        with torch.no_grad():
            residual = torch.cat([det.model_(x[i:i + 256]) - x[i:i + 256]
                                  for i in range(0, len(x), 256)]).numpy()
        learned = instance_auc(test.y, glr.channel_scores(residual))
        rows.append(f"| {stage} | {oracle:.3f} | {estimated:.3f} | {paper:.3f} | {learned:.3f} | "
                    f"{fit_s:.0f} |")
        print(rows[-1], flush=True)
    lines = [
        "# GLR scoring of residuals: the scoring or the model?",
        "",
        f"`make bench-residual-glr` (`python -m benchmarks residual_glr`), "
        f"{datetime.date.today().isoformat()}, {cpu_name()}, 2 cores, torch "
        f"{torch.__version__}. Instance ROC-AUC, {N_TRAIN:,} training / {N_TEST:,} test windows "
        f"(seeds 0 / 1), CNN autoencoder at the quick preset's {EPOCHS} epochs.",
        "",
        *rows,
        "",
        "Reading: the oracle column is the ceiling; the next shows what estimating the noise "
        "level (one change point per window and channel) costs; the last two are the same "
        "trained network scored two ways.",
    ]
    write_markdown("docs/results/detectors/residual-glr.md", lines)


if __name__ == "__main__":
    main()
