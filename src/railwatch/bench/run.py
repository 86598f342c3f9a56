"""The benchmark grid: stages × detectors × seeds, every cell independent and resumable.

A cell generates (or reads from the on-disk cache) its stage's train and test sets, fits one
detector on the training windows without labels, scores the test windows, and returns one record
of metrics and timings plus a few small arrays for the figures. The driver writes each finished
cell to ``OUT/cells/`` atomically, so an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import platform
import shutil
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from railwatch.atomic import atomic_path, remove_stale_temporaries, sha256_file
from railwatch.bench.presets import Preset
from railwatch.synthetic import SPEC_VERSION, SyntheticSet, generate

if TYPE_CHECKING:  # torch is imported only when a cell runs
    from railwatch.detectors.api import Detector

log = logging.getLogger(__name__)

#: Detectors whose attention maps feed the report's attention figure.
ATTENTION_DETECTORS = ("aft-attention",)
#: Anomalous test windows whose scores (and attention, where there is some) are kept per cell.
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


def dataset(cache: Path, stage: int, seed: int, n: int, split: str) -> SyntheticSet:
    """A stage's train or test set, generated once and cached by stage, seed, size and spec."""
    path = cache / f"stage{stage}-seed{seed}-{split}-n{n}-spec{SPEC_VERSION}.npz"
    if path.exists():
        try:
            return SyntheticSet.load(path)
        except Exception:  # noqa: BLE001 - a damaged cache file is regenerated
            log.warning("regenerating damaged cache file %s", path)
    data = generate(stage, n, data_seed(seed, split), components=True)
    cache.mkdir(parents=True, exist_ok=True)
    data.save(path)
    return data


def cpu_name() -> str:
    """The processor's model name (Linux), else what ``platform`` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def environment() -> dict[str, Any]:
    """Where a cell ran: CPU, cores, threads, torch version, GPU."""
    import torch

    return {
        "cpu": cpu_name(), "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
        else os.cpu_count(), "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "python": platform.python_version(), "host": platform.node(),
    }


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

    folder = cache / "models" / training_key(det, cell, preset)
    info_path = folder / "fit.json"
    if info_path.exists():
        try:
            info = json.loads(info_path.read_text())
            trained = load_detector(folder)
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
    try:
        os.rename(private, folder)
    except OSError:  # another cell saved it first
        shutil.rmtree(private, ignore_errors=True)
    return det, fit_s, cell.detector


def cell_detector(cell: Cell, preset: Preset) -> Detector:
    """The unfitted detector of a cell: the preset's overrides, the cell's seed, silent."""
    from railwatch.detectors import create

    return create(cell.detector, {**preset.overrides_for(cell.detector), "seed": cell.seed,
                                  "progress": False})


def side_arrays(det: Detector, data: SyntheticSet) -> dict[str, Any] | None:
    """The generator's components for a detector that needs them (the oracle), else None."""
    return {"nuisance": data.nuisance, "noise_std": data.noise_std} if det.needs else None


def run_cell(cell: Cell, preset: Preset, cache: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """Fit and evaluate one detector on one stage and seed: (record, small arrays)."""
    from railwatch.evaluation.metrics import evaluate_scores, timed_scores

    cell_started = time.perf_counter()
    train = dataset(cache, cell.stage, cell.seed, preset.n_train, "train")
    test = dataset(cache, cell.stage, cell.seed, preset.n_test, "test")
    det = cell_detector(cell, preset)

    def ctx(d: SyntheticSet) -> dict[str, Any] | None:
        return side_arrays(det, d)

    det, fit_s, trained_by = fit_or_reuse(det, cell, preset, cache, train.X, ctx(train))
    score_s, scores = timed_scores(det, test.X, ctx(test), repeats=preset.timing_repeats)
    metrics = evaluate_scores(test.y, test.mask, test.channel, scores, det.threshold_)

    examples = np.flatnonzero(test.y)[:N_EXAMPLES]
    arrays: dict[str, Any] = {
        "instance": scores.instance, "y": test.y, "kind": test.kind,
        "example_index": examples, "example_point": scores.point[examples],
        "example_channel": scores.channel[examples],
    }
    if cell.detector in ATTENTION_DETECTORS:
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


# ----------------------------------------------------------------------------- the store
class ResultStore:
    """Finished cells on disk: ``cells/<key>.json`` (record) and ``cells/<key>.npz`` (arrays).

    Both are written atomically, the arrays first; the record, written last, marks the cell done
    and holds the SHA-256 of the arrays file, so a cell whose files were damaged afterwards (or
    whose arrays belong to another run) is computed again instead of being reused. One run at a
    time writes into a folder: :meth:`lock` takes ``OUT/.lock`` (released by the system when the
    process dies, however it dies) and clears what killed runs left half-written.
    """

    def __init__(self, out: Path) -> None:
        self.out = out
        self.dir = out / "cells"
        self.cache = out / "cache"

    def lock(self) -> Any:
        """Hold the folder for this process (a context manager); one-line error if taken."""
        return _FolderLock(self.out, self._clean)

    def _clean(self) -> None:
        """Remove temporary files and folders of killed runs (safe: we hold the lock)."""
        removed = sum(remove_stale_temporaries(d) for d in (self.out, self.dir, self.cache)
                      if d.is_dir())
        models = self.cache / "models"
        if models.is_dir():
            for stale in models.glob(".*"):
                shutil.rmtree(stale, ignore_errors=True)
                removed += 1
        if removed:
            log.info("removed %d temporary file(s) left by an interrupted run", removed)

    def done(self, preset: Preset, cell: Cell) -> bool:
        """Whether ``cell`` is finished, for this preset, with intact files."""
        path, arrays = self.dir / f"{cell.key}.json", self.dir / f"{cell.key}.npz"
        if not path.exists():
            return False
        try:
            record = json.loads(path.read_text())
            if record.get("fingerprint") != fingerprint(preset, cell):
                return False
            if "arrays_sha256" not in record:
                log.info("computing %s again: written by an older railwatch", cell.key)
                return False
            if record["arrays_sha256"] != sha256_file(arrays):
                raise ValueError("its arrays file does not match its record")
            return True
        except (OSError, ValueError, AttributeError) as e:
            log.warning("computing %s again: its result files are damaged (%s)", cell.key,
                        " ".join(str(e).split())[:120])
            return False

    def write(self, cell: Cell, record: dict[str, Any], arrays: dict[str, Any]) -> None:
        self.dir.mkdir(parents=True, exist_ok=True)
        target = self.dir / f"{cell.key}.npz"
        with atomic_path(target) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
        self.write_record(cell, {**record, "arrays_sha256": sha256_file(target)})  # marks it done

    def write_record(self, cell: Cell, record: dict[str, Any]) -> None:
        """Write (or replace) a cell's record; a finished cell's arrays stay."""
        with atomic_path(self.dir / f"{cell.key}.json") as tmp:
            tmp.write_text(json.dumps(record, indent=1, default=_json_default))

    def record(self, cell: Cell) -> dict[str, Any]:
        return dict(json.loads((self.dir / f"{cell.key}.json").read_text()))

    def arrays(self, cell: Cell) -> dict[str, Any]:
        with np.load(self.dir / f"{cell.key}.npz", allow_pickle=False) as f:
            return {k: f[k] for k in f.files}


class _FolderLock:
    """An exclusive ``flock`` on ``folder/.lock`` for the life of a ``with`` block; re-entrant
    in one process (the CLI holds it around a run and its report, ``run_grid`` inside)."""

    _held: ClassVar[dict[Path, int]] = {}

    def __init__(self, folder: Path, on_acquire: Callable[[], None]) -> None:
        self.path = (folder / ".lock").resolve()
        self.on_acquire = on_acquire
        self.fh: Any = None

    def __enter__(self) -> _FolderLock:
        import fcntl

        if self.path in self._held:
            self._held[self.path] += 1
            return self
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.fh = open(self.path, "a+")
        try:
            fcntl.flock(self.fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self.fh.seek(0)
            holder = self.fh.read().strip() or "another process"
            self.fh.close()
            from railwatch.errors import RailwatchError

            raise RailwatchError(f"{self.path.parent} is in use by another railwatch run "
                                 f"({holder}): wait for it to finish or give another --out") \
                from None
        self.fh.seek(0)
        self.fh.truncate()
        self.fh.write(f"pid {os.getpid()} on {platform.node()}\n")
        self.fh.flush()
        self._held[self.path] = 1
        try:
            self.on_acquire()
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        import fcntl

        self._held[self.path] -= 1
        if self._held[self.path] == 0 and self.fh is not None:
            del self._held[self.path]
            fcntl.flock(self.fh, fcntl.LOCK_UN)
            self.fh.close()


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, tuple | set):
        return list(value)
    raise TypeError(f"cannot store {type(value).__name__} in results")


def _nan_to_none(value: Any) -> Any:
    if isinstance(value, float) and value != value:
        return None
    return value


# ----------------------------------------------------------------------------- executors
CellResult = tuple[Cell, dict[str, Any], dict[str, Any]]


def execute_local(todo: list[Cell], preset: Preset, cache: Path) -> Iterator[CellResult]:
    """In-process, one cell after another."""
    for cell in todo:
        record, arrays = run_cell(cell, preset, cache)
        yield cell, record, arrays


def execute_ray(
    todo: list[Cell], preset: Preset, cache: Path, address: str | None = None
) -> Iterator[CellResult]:
    """Every cell a Ray task (one CPU each), yielded as they finish.

    ``address`` joins an existing cluster; without it a local Ray starts on this machine. Tasks
    generate their data themselves (deterministically, cached on their node's disk under the same
    path) and send back records and small arrays; only the driver writes results.
    """
    try:
        import ray
    except ImportError:
        from railwatch.errors import RailwatchError

        raise RailwatchError("--executor ray needs Ray: pip install 'railwatch[ray]'") from None
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(address=address, include_dashboard=False, log_to_driver=False,
                 logging_level=logging.WARNING)
    try:
        remote = ray.remote(num_cpus=1)(_ray_cell)
        pending = {remote.remote(cell, preset, str(cache)): cell for cell in todo}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            cell = pending.pop(ready[0])
            record, arrays = ray.get(ready[0])
            yield cell, record, arrays
    finally:
        if started_here:
            ray.shutdown()


def _ray_cell(cell: Cell, preset: Preset, cache: str) -> tuple[dict[str, Any], dict[str, Any]]:
    import torch

    torch.set_num_threads(1)  # one CPU per task
    return run_cell(cell, preset, Path(cache))


def run_grid(
    preset: Preset,
    out: Path,
    executor: str = "local",
    address: str | None = None,
    on_cell: Callable[[Cell, dict[str, Any] | None, int, int], None] | None = None,
) -> list[dict[str, Any]]:
    """Run every unfinished cell of ``preset`` into ``out``; return all records, grid order.

    ``on_cell(cell, record, done, total)`` is called once per cell as it finishes (``record`` is
    None for a cell found finished on disk).
    """
    store = ResultStore(out)
    with store.lock():
        return _run_grid(store, preset, executor, address, on_cell)


def _run_grid(
    store: ResultStore, preset: Preset, executor: str, address: str | None,
    on_cell: Callable[[Cell, dict[str, Any] | None, int, int], None] | None,
) -> list[dict[str, Any]]:
    grid = cells(preset)
    todo = [c for c in grid if not store.done(preset, c)]
    done = len(grid) - len(todo)
    if on_cell is not None:
        for c in grid:
            if c not in todo:
                on_cell(c, None, done, len(grid))
    results: Iterable[CellResult]
    if executor == "local":
        results = execute_local(todo, preset, store.cache)
    elif executor == "ray":
        results = execute_ray(todo, preset, store.cache, address)
    else:
        from railwatch.errors import RailwatchError

        raise RailwatchError(f"unknown executor {executor!r}: use local or ray")
    for cell, record, arrays in results:
        store.write(cell, record, arrays)
        done += 1
        if on_cell is not None:
            on_cell(cell, record, done, len(grid))
    return [{k: _nan_to_none(v) for k, v in store.record(c).items()} for c in grid]


#: Timed scorings per cell when re-timing (median).
RETIME_REPEATS = 3


def retime(preset: Preset, out: Path,
           on_cell: Callable[[Cell, dict[str, Any] | None, int, int], None] | None = None) -> int:
    """Re-measure ``score_s`` of every finished cell from its saved model; returns the count.

    For a run made while other work shared the machine: the AUCs stay, the scoring times are
    measured again (median of :data:`RETIME_REPEATS` after a warm-up batch) and the record notes
    the date (``score_retimed``). Cells without a saved model are left as they are.
    """
    store = ResultStore(out)
    with store.lock():
        return _retime(store, preset, on_cell)


def _retime(store: ResultStore, preset: Preset,
            on_cell: Callable[[Cell, dict[str, Any] | None, int, int], None] | None) -> int:
    import datetime
    from dataclasses import replace

    from railwatch.detectors.registry import load_detector
    from railwatch.evaluation.metrics import score_seconds

    grid = [c for c in cells(preset) if store.done(preset, c)]
    count = 0
    for i, cell in enumerate(grid):
        det = cell_detector(cell, preset)
        folder = store.cache / "models" / training_key(det, cell, preset)
        record = None
        if (folder / "fit.json").exists():
            trained = load_detector(folder)
            trained.config = replace(trained.config, **{f: getattr(det.config, f)
                                                        for f in det.scoring_fields})
            test = dataset(store.cache, cell.stage, cell.seed, preset.n_test, "test")
            record = store.record(cell)
            record["score_s"] = score_seconds(trained, test.X, side_arrays(trained, test),
                                              repeats=RETIME_REPEATS)
            record["score_retimed"] = datetime.date.today().isoformat()
            store.write_record(cell, record)
            count += 1
        if on_cell is not None:
            on_cell(cell, record, i + 1, len(grid))
    return count
