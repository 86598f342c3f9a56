"""How much of the stage-1 anomalies can a representation show at all? A supervised bound.

Two targets of the detectors issue are unmet at stage 1: MSCRED ≥ 0.90 and the attention model's
`attention` score ≥ 0.95. Is that the training or scoring, or does the representation each one
scores (MSCRED's signature matrices; the attention model's attention maps) not carry the
information? This script trains the *same supervised classifier*, with the labels, on each
representation of the same windows and reports its instance ROC-AUC next to the unsupervised
detector that scores that representation. A detector trained without labels is not expected to
beat the supervised classifier on its own representation (the classifier is an estimate of the
ceiling, not a proof: a stronger classifier could do better).

Representations, each a sequence over time of feature vectors (N, steps, features):

- `raw window`: the window itself, divided by its own standard deviation (what the
  reconstruction detectors and the oracle see);
- `mscred signature matrices`: the fitted MSCRED's own signature matrices (its min-max scaling
  to [-1, 1]), the real C×C entries of the three scales at each of the 20 steps; and the same with
  the inputs scaled to [0, 1], the other reading of the spec's "min-max normalised";
- `aft attention features`: the fitted attention model's standardised, window-relative attention
  features (per layer and head: mass received, row entropy, self-weight; each token's value
  repeated over its 8 samples) and its per-sample input-attention deviation: exactly what the
  `attention` score combines;
- `aft reconstruction error`: the same network's per-sample log relative squared error (what the
  `reconstruction` score uses).

The classifier: a dilated 1-D CNN (64 filters, kernel 5, dilations 1, 2, 4: a 29-step receptive
field; replicate padding; batch normalisation) with a global max over time, trained with binary
cross-entropy on 20,000 labelled stage-1 windows (seed 2, 10 epochs, Adam 1e-3). Test: 5,000
windows (seed 1). The unsupervised detectors are fitted on 2,000 unlabelled windows (seed 0) as in
`make bench-detectors`.

Run: `make bench-representation-bounds` (about 5 minutes on 2 cores); writes
docs/results/detectors/representation-bounds.md.
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from sklearn.metrics import roc_auc_score
from torch import nn
from torch.nn import functional as F

from railwatch.detectors import create
from railwatch.detectors.api import Detector
from railwatch.detectors.mscred import signature_matrices
from railwatch.machine import cpu_name
from railwatch.report.pages import write_markdown
from railwatch.synthetic import generate

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/detectors/representation-bounds.md"
MINUTES = 5

Features = Callable[[np.ndarray], np.ndarray]  # windows (N, T, 1) -> (N, steps, features)


class Classifier(nn.Module):
    """Dilated 1-D CNN over time with a global max: one logit per window."""

    def __init__(self, n_features: int, width: int = 64) -> None:
        super().__init__()
        self.dilations = (1, 2, 4)
        chans = (n_features, width, width, width)
        self.convs = nn.ModuleList(nn.Conv1d(chans[i], chans[i + 1], 5, dilation=d)
                                   for i, d in enumerate(self.dilations))
        # Batch normalisation: without it the max-pooled CNN often stalls (raw windows: 0.74
        # instead of 0.99 after 5 epochs).
        self.norms = nn.ModuleList(nn.BatchNorm1d(width) for _ in self.dilations)
        self.head = nn.Conv1d(width, 1, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, steps, F) -> (B,)
        h = x.transpose(1, 2)
        for conv, norm, d in zip(self.convs, self.norms, self.dilations, strict=True):
            h = F.relu(norm(conv(F.pad(h, (2 * d, 2 * d), mode="replicate"))))
        return self.head(h).amax(dim=2)[:, 0]


def supervised_scores(f_train: np.ndarray, y_train: np.ndarray, f_test: np.ndarray,
                      epochs: int) -> np.ndarray:
    torch.manual_seed(0)
    xt = torch.from_numpy(f_train).float()
    mu, sd = xt.mean(dim=(0, 1)), xt.std(dim=(0, 1)).clamp_min(1e-6)
    xt = (xt - mu) / sd
    yt = torch.from_numpy(y_train).float()
    net = Classifier(xt.shape[2])
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    for _ in range(epochs):
        perm = torch.randperm(len(xt))
        for i in range(0, len(xt), 128):
            b = perm[i:i + 128]
            loss = F.binary_cross_entropy_with_logits(net(xt[b]), yt[b])
            opt.zero_grad()
            loss.backward()
            opt.step()
    net.eval()
    with torch.no_grad():
        xs = (torch.from_numpy(f_test).float() - mu) / sd
        return torch.cat([net(xs[i:i + 1024]) for i in range(0, len(xs), 1024)]).numpy()


def aucs(y: np.ndarray, kind: np.ndarray, s: np.ndarray) -> tuple[float, float, float]:
    """Instance ROC-AUC overall, spikes only and local deviations only (each against normals)."""
    out = [roc_auc_score(y, s)]
    for k in (1, 2):
        keep = (kind == 0) | (kind == k)
        out.append(roc_auc_score(y[keep], s[keep]))
    return out[0], out[1], out[2]


def raw_window(X: np.ndarray) -> np.ndarray:
    return X / X.std(axis=1, keepdims=True)


def mscred_signatures(det: Detector, low: float = -1.0) -> Features:
    """The fitted MSCRED's signature matrices, inputs min-max scaled to [low, 1] (the detector
    itself uses [-1, 1])."""
    lo, rng = det.stats_["input_min"], det.stats_["input_range"]
    cfg: Any = det.config

    def features(X: np.ndarray) -> np.ndarray:
        scaled = torch.from_numpy(low + (1 - low) * (X - lo) / rng)
        sig = signature_matrices(scaled, cfg.scales, cfg.gap)
        return sig[..., :X.shape[2], :X.shape[2]].flatten(2).numpy()  # real entries, (N, K, S·C·C)
    return features


def aft_attention(det: Detector) -> Features:
    def features(X: np.ndarray) -> np.ndarray:
        raw = det.raw_outputs(det.normalized(X))  # type: ignore[attr-defined]
        z_enc, z_inp = det.attention_z(raw)  # type: ignore[attr-defined]  # (N,C,F,L), (N,T,C)
        n, _, _, n_tok = z_enc.shape
        per_sample = np.repeat(z_enc[:, 0], det.config.patch, axis=-1)  # type: ignore[attr-defined]
        per_sample = per_sample[..., :X.shape[1]].transpose(0, 2, 1)  # (N, T, F)
        return np.concatenate([per_sample, z_inp], axis=2)
    return features


def aft_reconstruction(det: Detector) -> Features:
    def features(X: np.ndarray) -> np.ndarray:
        raw = det.raw_outputs(det.normalized(X))  # type: ignore[attr-defined]
        return det.reconstruction_channel(raw)  # type: ignore[attr-defined]  # (N, T, 1)
    return features


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--labelled", type=int, default=20000, help="labelled training windows")
    parser.add_argument("--test", type=int, default=5000, help="test windows")
    parser.add_argument("--epochs", type=int, default=10, help="classifier epochs")
    parser.add_argument("--out", default=PAGE)
    args = parser.parse_args()

    unlabelled = generate(1, 2000, 0)
    labelled = generate(1, args.labelled, 2)
    test = generate(1, args.test, 1)
    fitted = {name: create(name, {"progress": False}).fit(unlabelled.X)
              for name in ("mscred", "aft-attention", "cnn-ae")}
    fitted["aft-reconstruction"] = fitted["aft-attention"].rescored(
        unlabelled.X, scoring="reconstruction")
    rows = [  # representation, its features, the unsupervised detector that scores it
        ("raw window", raw_window, "cnn-ae"),
        ("mscred signature matrices", mscred_signatures(fitted["mscred"]), "mscred"),
        ("mscred signature matrices, inputs scaled to [0, 1]",
         mscred_signatures(fitted["mscred"], low=0.0), "mscred"),
        ("aft attention features", aft_attention(fitted["aft-attention"]), "aft-attention"),
        ("aft reconstruction error", aft_reconstruction(fitted["aft-attention"]),
         "aft-reconstruction"),
    ]
    table = []
    for rep, features, detector in rows:
        bound = aucs(test.y, test.kind, supervised_scores(
            features(labelled.X), labelled.y, features(test.X), args.epochs))
        unsup = aucs(test.y, test.kind, fitted[detector].score(test.X).instance)
        table.append((rep, bound, detector, unsup))
        print(f"{rep}: supervised {bound[0]:.3f}; {detector} {unsup[0]:.3f}", file=sys.stderr)

    def fmt(a: tuple[float, float, float]) -> str:
        return f"{a[0]:.3f} | {a[1]:.3f} | {a[2]:.3f}"

    lines = [
        "# Stage 1: what each representation can show (a supervised bound)", "",
        f"`python -m benchmarks representation_bounds` on {datetime.date.today()}: {cpu_name()}, "
        f"{len(os.sched_getaffinity(0))} cores, torch {torch.__version__}. Supervised "
        f"classifier: dilated 1-D CNN with a global max, {args.labelled:,} labelled windows, "
        f"{args.epochs} epochs; unsupervised detectors: 2,000 unlabelled windows, default "
        f"settings; every AUC on the same {args.test:,} test windows (instance ROC-AUC; spikes "
        "and local deviations each against the normal windows). See the script's docstring.", "",
        "| representation | supervised AUC | spikes | local | unsupervised detector on it "
        "| AUC | spikes | local |",
        "|---|---|---|---|---|---|---|---|",
    ]
    lines += [f"| {rep} | {fmt(b)} | {det} | {fmt(u)} |" for rep, b, det, u in table]
    print(write_markdown(args.out, lines), end="")


if __name__ == "__main__":
    main()
