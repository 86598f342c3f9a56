"""Where context-glr loses against the oracle: its prediction of the normal signal, or the scoring.

    python -m benchmarks context_glr [STAGES]     # make bench-context-glr (default 1,4,5,7,8)

Per stage, at the quick preset's sizes (2,000 training and 1,000 test windows, seeds 0 / 1), with
context-glr at its default size:

- instance ROC-AUC with the learned noise scale (the default) and with the change-point scale
  estimated from the residual (``scale=changepoint``, the same trained network);
- the prediction error against the generator's true nuisance, ``rms(μ − nuisance)``, divided by
  the true noise std ``rms(noise_std)``, both in the detector's normalised units: 0 for the oracle;
- the **supervised bound**: the same blind-spot network, same training, but fitted to the true
  nuisance (mean-squared error) instead of the noisy window: what the architecture can represent
  at this training size, whatever the unsupervised training signal.

If the supervised network predicts no better than the unsupervised one, the loss is the
architecture's (what a blind-spot CNN of this size can learn from 2,000 windows), not the
contamination or the self-supervised target. Writes docs/results/detectors/context-glr.md.
"""

from __future__ import annotations

import datetime
import sys
import time

import numpy as np
import torch
from sklearn.metrics import roc_auc_score

from railwatch.detectors import create
from railwatch.detectors.context_glr import BlindSpotNet, ContextGLR, inject_defects
from railwatch.machine import cpu_name
from railwatch.report.pages import write_markdown
from railwatch.scoring.residual import ResidualGLR
from railwatch.synthetic import generate
from railwatch.windows import WindowSet

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/detectors/context-glr.md"
MINUTES = 10

N_TRAIN, N_TEST = 2000, 1000


def error_ratio(det: ContextGLR, X: np.ndarray, nuisance: np.ndarray, noise: np.ndarray) -> float:
    """rms(μ − nuisance) / rms(noise std), both per channel in normalised units."""
    std = det.stats_["input_std"]
    x = det.normalized(X.astype(np.float32))
    mu = x - det.raw_outputs(x)["residual"]
    truth = (nuisance - det.stats_["input_mean"]) / std
    return float(np.sqrt(np.mean((mu - truth) ** 2)) / np.sqrt(np.mean((noise / std) ** 2)))


def supervised_bound(train: WindowSet, test: WindowSet) -> tuple[float, float]:
    """AUC (change-point scale) and error ratio of the network fitted to the true nuisance."""
    cfg = create("context-glr").config
    mean = train.X.mean(axis=(0, 1), dtype=np.float64).astype(np.float32)
    std = train.X.std(axis=(0, 1), dtype=np.float64).astype(np.float32)
    x = torch.from_numpy(((train.X - mean) / std).astype(np.float32))
    y = torch.from_numpy(((train.nuisance - mean) / std).astype(np.float32))
    torch.manual_seed(cfg.seed)
    net = BlindSpotNet(cfg.width, cfg.dilations, cfg.kernel, cfg.gap)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda e: 0.5 * (1.0 + np.cos(np.pi * min(e, cfg.epochs) / cfg.epochs)))
    gen = torch.Generator().manual_seed(cfg.seed)
    for _ in range(cfg.epochs):
        net.train()
        perm = torch.randperm(len(x), generator=gen)
        for i in range(0, len(x), cfg.batch_size):
            idx = perm[i:i + cfg.batch_size]
            pick = torch.randint(0, x.shape[2], (len(idx),), generator=gen)  # as the detector
            xb, yb = x[idx, :, pick][..., None], y[idx, :, pick][..., None]
            seen = inject_defects(xb, cfg.inject, cfg.inject_size, cfg.min_box, cfg.max_box, gen)
            loss = torch.nn.functional.mse_loss(net(seen)[0], yb)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        sched.step()
    net.eval()
    xt = torch.from_numpy(((test.X - mean) / std).astype(np.float32))
    with torch.no_grad():
        mu = torch.cat([net(xt[i:i + 256])[0] for i in range(0, len(xt), 256)]).numpy()
    truth = (test.nuisance - mean) / std
    ratio = float(np.sqrt(np.mean((mu - truth) ** 2)) / np.sqrt(np.mean((test.noise_std / std)
                                                                         ** 2)))
    channel = ResidualGLR(null_windows=cfg.null_windows).channel_scores(xt.numpy() - mu)
    return float(roc_auc_score(test.y, channel.max(axis=(1, 2)))), ratio


def main() -> None:
    stages = [int(s) for s in sys.argv[1].split(",")] if len(sys.argv) > 1 else [1, 4, 5, 7, 8]
    rows = ["| stage | AUC, learned scale | AUC, change-point scale | prediction error / noise | "
            "supervised bound: AUC (change-point scale) | supervised bound: error / noise | "
            "fit (s) |", "|---|---|---|---|---|---|---|"]
    for stage in stages:
        train = generate(stage, N_TRAIN, 0, components=True)
        test = generate(stage, N_TEST, 1, components=True)
        started = time.perf_counter()
        det = create("context-glr", {"progress": False}).fit(train.X)
        fit_s = time.perf_counter() - started
        learned = float(roc_auc_score(test.y, det.score(test.X).instance))
        cp = det.rescored(train.X, scale="changepoint")
        changepoint = float(roc_auc_score(test.y, cp.score(test.X).instance))
        ratio = error_ratio(det, test.X, test.nuisance, test.noise_std)
        bound_auc, bound_ratio = supervised_bound(train, test)
        rows.append(f"| {stage} | {learned:.3f} | {changepoint:.3f} | {ratio:.2f} | "
                    f"{bound_auc:.3f} | {bound_ratio:.2f} | {fit_s:.0f} |")
        print(rows[-1], flush=True)
    lines = [
        "# context-glr: the prediction or the scoring?",
        "",
        f"`make bench-context-glr` (`python -m benchmarks context_glr`), "
        f"{datetime.date.today().isoformat()}, {cpu_name()}, 2 cores, torch {torch.__version__}. "
        f"{N_TRAIN:,} training / {N_TEST:,} test windows (seeds 0 / 1), context-glr at its "
        "default size (width 64, 25 epochs).",
        "",
        *rows,
        "",
        "Prediction error / noise: `rms(μ − true nuisance) / rms(true noise std)`, normalised "
        "units; 0 is the oracle. The supervised bound trains the same blind-spot network on the "
        "true nuisance (mean-squared error, the same injected defects in its input) and scores "
        "its residual with the change-point scale.",
    ]
    write_markdown("docs/results/detectors/context-glr.md", lines)


if __name__ == "__main__":
    main()
