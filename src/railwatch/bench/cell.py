"""One cell of the benchmark grid: a stage, a detector and a seed, independent of every other.

A cell generates (or reads from the on-disk cache) its stage's train and test sets, fits one
detector on the training windows without labels, scores the test windows, and returns one record
of metrics and timings plus a few small arrays for the figures.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from railwatch.bench.presets import Preset
from railwatch.machine import environment
from railwatch.synthetic import SPEC_VERSION, generate
from railwatch.windows import WindowSet

if TYPE_CHECKING:  # torch is imported only when a cell runs
    from railwatch.detectors.api import Detector

log = logging.getLogger(__name__)

#: Anomalous test windows whose scores (and maps, where the detector has them) are kept per cell.
N_EXAMPLES = 4


@dataclass(frozen=True)
class Cell:
    stage: int
    detector: str
    seed: int

    @property
    def key(self) -> str:
        return f"stage{self.stage}-{self.detector}-seed{self.seed}"


def cells(preset: Preset) -> list[Cell]:
    """Every cell of the grid, stage-major so that tables fill in stage order."""
    return [Cell(s, d, k) for s in preset.stages for k in range(preset.seeds)
            for d in preset.detectors]


def fingerprint(preset: Preset, cell: Cell) -> str:
    """What makes a finished cell reusable: data sizes, spec version and detector overrides."""
    spec = {"n_train": preset.n_train, "n_test": preset.n_test, "spec": SPEC_VERSION,
            "overrides": preset.overrides_for(cell.detector),
            "timing_repeats": preset.timing_repeats}
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:10]


def data_seed(seed: int, split: str) -> int:
    """Train and test sets of one benchmark seed come from different generator seeds."""
    return 2 * seed + (split == "test")


def dataset(cache: Path, stage: int, seed: int, n: int, split: str) -> WindowSet:
    """A stage's train or test set, generated once and cached by stage, seed, size and spec."""
    path = cache / f"stage{stage}-seed{seed}-{split}-n{n}-spec{SPEC_VERSION}.npz"
    if path.exists():
        try:
            return WindowSet.load(path)
        except Exception:  # noqa: BLE001 - a damaged cache file is regenerated
            log.warning("regenerating damaged cache file %s", path)
    data = generate(stage, n, data_seed(seed, split), components=True)
    cache.mkdir(parents=True, exist_ok=True)
    data.save(path)
    return data


def training_key(det: Detector, cell: Cell, preset: Preset) -> str:
    """What a fitted model depends on: class, config without scoring-only fields, data."""
    learned = {k: v for k, v in asdict(det.config).items()
               if k not in det.scoring_fields and k != "progress"}
    spec = {"class": f"{type(det).__module__}.{type(det).__qualname__}", "config": learned,
            "stage": cell.stage, "seed": cell.seed, "n_train": preset.n_train,
            "spec": SPEC_VERSION}
    digest = hashlib.sha256(json.dumps(spec, sort_keys=True, default=str).encode()).hexdigest()
    return f"stage{cell.stage}-seed{cell.seed}-{digest[:12]}"


def fit_or_reuse(
    det: Detector, cell: Cell, preset: Preset, cache: Path, X: Any, context: Any
) -> tuple[Detector, float, str]:
    """Fit ``det`` on the training windows, or reuse a model trained the same way.

    Detectors of one class whose configs differ only in scoring-only fields (the attention
    model's ``attention``, ``reconstruction`` and ``combined`` rows) share one trained model,
    kept under ``cache/models/``; the reusing cell refits only its threshold. Cells running at
    the same time (Ray) may each train it (identically: same seed) before one has saved it.
    Returns the detector, the fit seconds (the shared training's plus the refit) and the
    registry name of the cell that trained the network.
    """
    from railwatch.detectors.registry import load_detector
    from railwatch.detectors.training import TorchDetector

    key = training_key(det, cell, preset)
    folder = cache / "models" / key
    info_path = folder / "fit.json"
    if info_path.exists():
        try:
            info = json.loads(info_path.read_text())
            trained = load_detector(folder)
            if isinstance(trained, TorchDetector) and (folder / FIT_RESIDUAL).exists():
                with np.load(folder / FIT_RESIDUAL) as kept:
                    trained.fit_residual_ = kept["residual"]
                    trained.fit_digest_ = str(kept["digest"])
            started = time.perf_counter()
            reused = trained.rescored(X, context, **{f: getattr(det.config, f)
                                                     for f in det.scoring_fields})
            reused.registry_name = cell.detector
            return reused, float(info["fit_s"]) + time.perf_counter() - started, info["detector"]
        except Exception:  # noqa: BLE001 - an unreadable shared model is trained again
            log.warning("training again: cannot reuse the model in %s", folder)
    started = time.perf_counter()
    det.fit(X, context)
    fit_s = time.perf_counter() - started
    # Saved under a private name, then renamed: parallel cells (Ray) that trained the same model
    # do not write into one folder; the first rename wins, the others are dropped.
    folder.parent.mkdir(parents=True, exist_ok=True)
    private = folder.with_name(f".{folder.name}.{os.getpid()}-{time.monotonic_ns()}")
    det.save(private, extra_files={"fit.json": json.dumps({"fit_s": fit_s,
                                                           "detector": cell.detector})})
    if isinstance(det, TorchDetector) and det.fit_residual_ is not None and \
            _glr_row_reuses(key, cell, preset):
        np.savez(private / FIT_RESIDUAL, residual=det.fit_residual_,
                 digest=np.array(det.fit_digest_))
    try:
        os.rename(private, folder)
    except OSError:  # another cell saved it first
        shutil.rmtree(private, ignore_errors=True)
    return det, fit_s, cell.detector


#: Kept beside a shared model whose training a GLR-scored row reuses: the signed residual of the
#: training windows, so that the row refits its threshold without running the network over them
#: again (``TorchDetector.fit_residual_``; 75 of the quick run's 91 s beyond training and scoring).
FIT_RESIDUAL = "fit_residual.npz"


def _glr_row_reuses(key: str, cell: Cell, preset: Preset) -> bool:
    """Whether another row of ``preset``, scored by the GLR scan, reuses the model trained
    under ``key`` by ``cell``."""
    from railwatch.detectors.api import GLR_SCORING

    for name in (d for d in preset.detectors if d != cell.detector):
        other = Cell(cell.stage, name, cell.seed)
        det = cell_detector(other, preset)
        if getattr(det.config, "scoring", None) == GLR_SCORING and \
                training_key(det, other, preset) == key:
            return True
    return False


def cell_detector(cell: Cell, preset: Preset) -> Detector:
    """The unfitted detector of a cell: the preset's overrides, the cell's seed, silent."""
    from railwatch.detectors import create

    return create(cell.detector, {**preset.overrides_for(cell.detector), "seed": cell.seed,
                                  "progress": False})


def side_arrays(det: Detector, data: WindowSet) -> dict[str, Any] | None:
    """The side arrays a detector needs (the oracle: the generator's components), else None."""
    return {k: data.components.get(k) for k in det.needs} if det.needs else None


def run_cell(cell: Cell, preset: Preset, cache: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """Fit and evaluate one detector on one stage and seed: (record, small arrays)."""
    from railwatch.evaluation.metrics import evaluate_scores, timed_scores

    cell_started = time.perf_counter()
    train = dataset(cache, cell.stage, cell.seed, preset.n_train, "train")
    test = dataset(cache, cell.stage, cell.seed, preset.n_test, "test")
    det = cell_detector(cell, preset)

    def ctx(d: WindowSet) -> dict[str, Any] | None:
        return side_arrays(det, d)

    det, fit_s, trained_by = fit_or_reuse(det, cell, preset, cache, train.X, ctx(train))
    score_s, scores = timed_scores(det, test.X, ctx(test), repeats=preset.timing_repeats)
    y, mask, kind, channel = test.labels()
    metrics = evaluate_scores(y, mask, channel, scores, det.threshold_)

    examples = np.flatnonzero(y)[:N_EXAMPLES]
    arrays: dict[str, Any] = {
        "instance": scores.instance, "y": y, "kind": kind,
        "example_index": examples, "example_point": scores.point[examples],
        "example_channel": scores.channel[examples],
    }
    if det.report_maps:  # e.g. the attention model's maps, for the report's figure
        full = ctx(test)
        sub = {k: v[examples] for k, v in full.items()} if full else None
        extras = det.score(test.X[examples], sub, extras=True).extras
        arrays.update({f"extra_{k}": v for k, v in extras.items()})
    record = {
        "stage": cell.stage, "detector": cell.detector, "seed": cell.seed,
        "n_train": preset.n_train, "n_test": preset.n_test, "n_channels": int(test.X.shape[2]),
        **metrics, "fit_s": fit_s, "trained_by": trained_by, "score_s": score_s,
        "threshold": det.threshold_,
        "config": asdict(det.config), "environment": environment(),
        "fingerprint": fingerprint(preset, cell), "spec_version": SPEC_VERSION,
        "cell_s": time.perf_counter() - cell_started,  # the whole cell: data, fit, scoring
    }
    return record, arrays
