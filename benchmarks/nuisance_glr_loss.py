"""Where nuisance-glr loses against the oracle on the paper's windows, part by part.

    python -m benchmarks nuisance_glr_loss           # make bench-nuisance-glr-loss

The oracle scans ``(X − nuisance) / noise std`` with the generator's own nuisance signal and
noise level. nuisance-glr puts estimates in both places (`docs/nuisance-glr.md`). Each row below
gives it one more thing to estimate, so that the differences between rows are what each estimate
costs. Every row scans with nuisance-glr's calibrated spike and box tests; rows B-E whiten with
its own steps 2-4 (`NuisanceGLR.whitened`: the noise level, bursts and the synchronous level):

- A, the oracle: the true residual, divided by the true noise level;
- B: the true residual, whitened by nuisance-glr (its level estimated from the window);
- C: the harmonic model fitted to the noise-free nuisance (what the model cannot represent);
- D: the model fitted to the window less its anomaly (the model's frequency, speed change and
  fit estimated from noisy samples; the anomaly cannot pull it);
- E: the model fitted to the window: nuisance-glr's residual (the anomaly can pull the fit);
- F: nuisance-glr as it scores (E with the channels standardised by the training windows).

Rows A-E take the largest calibrated score over channels. Development seeds: `generate`'s 201
(2,000 training windows, for F's channel statistics) and 202 (2,000 test windows); the standard
preset's seeds (0-2) are not used. A second table splits stage 5 by the anomaly's kind and the
channel group it lies on. A third asks what the stage's own nuisance costs when everything else
is known: at stage 7 (bursts) and 8 (impulses), the residual of everything but it (the stage
before's nuisance: the generator's stages nest under one seed), divided by the true level or
whitened by nuisance-glr's steps 2-4 (its burst model, its synchronous level), and with the
impulse train fitted and taken out (`railwatch.scoring.impulses`; nuisance-glr's `impulses`,
off by default). Writes docs/results/detectors/nuisance-glr-loss.md.
"""

from __future__ import annotations

import argparse
import datetime
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from sklearn.metrics import roc_auc_score

from benchmarks.common import command
from railwatch.detectors import create
from railwatch.detectors.nuisance_glr import NuisanceGLR
from railwatch.machine import cpu_name
from railwatch.report.pages import write_markdown
from railwatch.scoring.glr import families, scale_counts, scan
from railwatch.synthetic import generate
from railwatch.windows import WindowSet

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/detectors/nuisance-glr-loss.md"
MINUTES = 6

TRAIN_SEED, TEST_SEED = 201, 202
ROWS = {
    "A": "oracle: true residual, true level",
    "B": "true residual, level estimated",
    "C": "model fitted to the noise-free nuisance",
    "D": "model fitted to the window less its anomaly",
    "E": "model fitted to the window (nuisance-glr's residual)",
    "F": "nuisance-glr (channels standardised)",
}
GROUPS = ("axle", "bogie", "body")
#: The stages whose own nuisance the third table leaves unknown, and what it is.
BLIND = {7: "bursts", 8: "impulses"}

F64 = NDArray[np.float64]


def series(a: NDArray[np.floating]) -> F64:
    """(N, T, C) -> (N·C, T), the detector's order of series."""
    n, t, c = a.shape
    return a.transpose(0, 2, 1).reshape(n * c, t).astype(np.float64)


def without_anomaly(ws: WindowSet) -> NDArray[np.floating]:
    """The windows less their anomaly's offset (the generator adds it where the mask is set)."""
    return ws.X - ws.labels()[1] * ws.params["anomaly_offset"][:, None, None]


def row_scores(det: NuisanceGLR, ws: WindowSet, row: str) -> F64:
    """Instance scores (N,) of ``row`` on ``ws``."""
    if row == "F":
        return np.asarray(det.score(ws.X).instance, dtype=np.float64)
    assert ws.nuisance is not None and ws.noise_std is not None
    x, clean = series(ws.X), series(ws.nuisance)
    fitted: dict[str, Callable[[], F64]] = {
        "A": lambda: clean, "B": lambda: clean, "C": lambda: det.nuisance(clean),
        "D": lambda: det.nuisance(series(without_anomaly(ws))),
        "E": lambda: det.nuisance(x)}
    r = x - fitted[row]()
    w = r / series(ws.noise_std) if row == "A" else det.whitened(r, None)[0]
    return scanned(det, w, ws.X.shape)


def scanned(det: NuisanceGLR, w: F64, shape: tuple[int, ...]) -> F64:
    """Instance scores (N,): nuisance-glr's calibrated spike and box scan of the whitened
    series ``w`` (N·C, T) of windows of ``shape`` (N, T, C), the largest over channels."""
    n, t, c = shape
    fams = families(det.config.min_box, det.config.max_box)
    counts = scale_counts(det.stats_["null_counts"], fams, det.n_steps_, t)
    norms = [[np.sqrt(L) for L in fam] for fam in fams]
    raw = scan(w.reshape(n, c, t).transpose(0, 2, 1), fams, norms, counts)
    return raw.max(axis=(1, 2))


def blind_scores(det: NuisanceGLR, ws: WindowSet, before: WindowSet, level: str) -> F64:
    """Instance scores (N,) of the residual of everything but the stage's own nuisance (``ws``
    less ``before``'s nuisance, the same seed one stage earlier), divided by the true ``level``
    (``level`` = "true", or "train": then less the impulse train fitted to it,
    :meth:`NuisanceGLR.impulse_train`) or whitened by
    nuisance-glr's steps 2-4 (``level`` = "estimated")."""
    assert before.nuisance is not None and ws.noise_std is not None
    r = series(ws.X) - series(before.nuisance)
    if level == "estimated":
        return scanned(det, det.whitened(r, None)[0], ws.X.shape)
    w = r / series(ws.noise_std)
    if level == "train":
        w = w - det.impulse_train(w).fit
    return scanned(det, w, ws.X.shape)


def by_kind_and_group(ws: WindowSet, scores: F64) -> dict[str, float]:
    """ROC-AUC of each anomaly kind on each channel group against all normal windows."""
    y, _, kinds, channel = ws.labels()
    group = np.array(ws.meta["groups"])
    out = {}
    for kind, name in ((1, "spike"), (2, "box")):
        for g in GROUPS:
            pos = (y == 1) & (kinds == kind) & (group[np.maximum(channel, 0)] == g)
            keep = pos | (y == 0)
            out[f"{name} on {g}"] = float(roc_auc_score(y[keep], scores[keep]))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=2000, help="training and test windows each")
    parser.add_argument("--stages", default="1,2,3,4,5,6,7,8")
    parser.add_argument("--out", default=PAGE)
    args = parser.parse_args()
    stages = [int(s) for s in args.stages.split(",")]
    start = time.time()
    table: dict[str, dict[int, float]] = {row: {} for row in ROWS}
    split: dict[str, dict[str, float]] = {}
    blind: dict[int, dict[str, float]] = {}
    for stage in stages:
        train = generate(stage, args.n, TRAIN_SEED)
        test = generate(stage, args.n, TEST_SEED, components=True)
        det = create("nuisance-glr", {"progress": False}).fit(train.X)
        assert isinstance(det, NuisanceGLR)
        for row in ROWS:
            scores = row_scores(det, test, row)
            table[row][stage] = float(roc_auc_score(test.y, scores))
            if stage == 5 and row in "ABDEF":
                split[row] = by_kind_and_group(test, scores)
        if stage in BLIND:
            before = generate(stage - 1, args.n, TEST_SEED, components=True)
            blind[stage] = {level: float(roc_auc_score(test.y, blind_scores(det, test, before,
                                                                            level)))
                            for level in ("true", "train", "estimated")}
            trains = create("nuisance-glr", {"progress": False, "impulses": True}).fit(train.X)
            assert isinstance(trains, NuisanceGLR)
            blind[stage]["trains estimated"] = float(roc_auc_score(
                test.y, blind_scores(trains, test, before, "estimated")))
            blind[stage]["trains"] = float(roc_auc_score(test.y, trains.score(test.X).instance))
        print(f"stage {stage}: " + ", ".join(f"{r} {table[r][stage]:.3f}" for r in ROWS),
              flush=True)
    lines = [
        "# Where nuisance-glr loses against the oracle on the paper's windows", "",
        f"`{command(__name__)}` (`make bench-nuisance-glr-loss`), {datetime.date.today()}, "
        f"{cpu_name()}, {time.time() - start:.0f} s. Instance ROC-AUC; development seeds: "
        f"{args.n:,} training windows (seed {TRAIN_SEED}) and {args.n:,} test windows "
        f"(seed {TEST_SEED}) per stage. Each row estimates one more thing than the row above "
        "(the module's docstring says how).", "",
        "| | " + " | ".join(f"stage {s}" for s in stages) + " |",
        "|---|" + "---|" * len(stages)]
    for row, name in ROWS.items():
        lines.append(f"| {row}. {name} | " + " | ".join(f"{table[row][s]:.3f}"
                                                        for s in stages) + " |")
    lines += ["", "What each estimate costs (the row above minus the row):", "",
              "| | " + " | ".join(f"stage {s}" for s in stages) + " |",
              "|---|" + "---|" * len(stages)]
    keys = list(ROWS)
    for above, row in zip(keys, keys[1:], strict=False):
        lines.append(f"| {above} − {row} | " + " | ".join(
            f"{table[above][s] - table[row][s]:+.3f}" for s in stages) + " |")
    if split:
        cols = list(next(iter(split.values())))
        lines += ["", "Stage 5 by the anomaly's kind and the channel group it lies on (each "
                  "against all normal windows):", "",
                  "| | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
        for row, values in split.items():
            lines.append(f"| {row}. {ROWS[row]} | " + " | ".join(f"{values[k]:.3f}"
                                                                for k in cols) + " |")
    if blind:
        at = list(blind)
        lines += ["", "What the stage's own nuisance costs when everything else is known (the "
                  "residual of everything but it):", "",
                  "| | " + " | ".join(f"stage {s} ({BLIND[s]})" for s in at) + " |",
                  "|---|" + "---|" * len(at),
                  "| A. oracle | " + " | ".join(f"{table['A'][s]:.3f}" for s in at) + " |",
                  "| B. true residual, whitened by nuisance-glr | "
                  + " | ".join(f"{table['B'][s]:.3f}" for s in at) + " |",
                  "| the stage's own nuisance unknown, true level, nothing to model it | "
                  + " | ".join(f"{blind[s]['true']:.3f}" for s in at) + " |",
                  "| ... true level, the impulse train fitted and taken out | "
                  + " | ".join(f"{blind[s]['train']:.3f}" for s in at) + " |",
                  "| ... whitened by nuisance-glr (its level, burst model and synchronous "
                  "level) | " + " | ".join(f"{blind[s]['estimated']:.3f}" for s in at) + " |",
                  "| ... whitened by nuisance-glr with `impulses=true` (the train fitted and "
                  "taken out first) | " + " | ".join(f"{blind[s]['trains estimated']:.3f}"
                                                     for s in at) + " |",
                  "| F. nuisance-glr | " + " | ".join(f"{table['F'][s]:.3f}" for s in at)
                  + " |",
                  "| F. nuisance-glr with `impulses=true` | " + " | ".join(
                      f"{blind[s]['trains']:.3f}" for s in at) + " |"]
    print(write_markdown(args.out, lines))


if __name__ == "__main__":
    main()
