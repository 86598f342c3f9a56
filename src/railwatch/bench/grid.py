"""The benchmark grid: stages × detectors × seeds, every cell independent and resumable.

The driver runs the unfinished cells on an executor (:mod:`railwatch.bench.executors`) and
writes each finished cell to ``OUT/cells/`` atomically (:mod:`railwatch.bench.store`), so an
interrupted run resumes where it stopped; :func:`retime` measures the scoring times again.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from railwatch.bench.cell import Cell, cell_detector, cells, dataset, side_arrays, training_key
from railwatch.bench.executors import CellResult, execute_local, execute_ray
from railwatch.bench.presets import Preset
from railwatch.bench.store import ResultStore, nan_to_none
from railwatch.errors import RailwatchError

if TYPE_CHECKING:
    from railwatch.report.run_report import AttentionExample


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
    return [{k: nan_to_none(v) for k, v in store.record(c).items()} for c in grid]


#: Timed scorings per cell when re-timing (median).
RETIME_REPEATS = 3


def retime(preset: Preset, out: Path,
           on_cell: Callable[[Cell, dict[str, Any] | None, int, int], None] | None = None) -> int:
    """Re-measure ``score_s`` of every finished cell from its saved model; returns the count.

    For a run made while other work shared the machine: the AUCs stay, the scoring times are
    measured again (median of :data:`RETIME_REPEATS` after a warm-up batch) and the record notes
    the date (``score_retimed``). Cells without a saved model are left as they are; a grid with
    unfinished cells is an error (run it first).
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

    missing = [c.key for c in cells(preset) if not store.done(preset, c)]
    if missing:
        raise RailwatchError(f"{len(missing)} cells of this grid are not finished (e.g. "
                             f"{missing[0]}): run without --retime first")
    grid = cells(preset)
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


def finished_grid(whole: Preset, out: Path, asked: Preset) -> Preset:
    """The grid whose report a folder can give: every stage and detector of ``whole`` with
    finished cells in ``out``, when those form a whole grid; else ``asked`` (a re-timed part of
    a run then rewrites the report of the run, not of the part)."""
    from dataclasses import replace

    store = ResultStore(out)
    done = [c for c in cells(whole) if store.done(whole, c)]
    found = replace(whole, stages=tuple(sorted({c.stage for c in done})),
                    detectors=tuple(d for d in whole.detectors
                                    if any(c.detector == d for c in done)))
    return found if done and len(done) == len(cells(found)) else asked


def write_run_report(out: Path, preset: Preset, records: list[dict[str, Any]],
                     wall_s: float | None = None) -> Path:
    """Hand a run's finished cells to the report (:mod:`railwatch.report.run_report`): records,
    the kept arrays of seed 0, the attention example and the stages' example windows; returns
    the path of report.html."""
    from railwatch.report.run_report import write_report
    from railwatch.synthetic import stage_examples

    store = ResultStore(out)
    seed0 = [c for c in cells(preset) if c.seed == 0 and store.done(preset, c)]
    arrays = {(c.stage, c.detector): store.arrays(c) for c in seed0}
    example = attention_example(preset, store, seed0, arrays)
    return write_report(out, preset, records, arrays, example, stage_examples(0), wall_s=wall_s)


def attention_example(preset: Preset, store: ResultStore, seed0: list[Cell],
                      arrays: dict[tuple[int, str], dict[str, Any]]) -> AttentionExample | None:
    """The first cell that kept attention maps (its detector's ``report_maps``), first anomalous
    test window (a local deviation if there is one, as it spans several tokens)."""
    import numpy as np

    from railwatch.report.run_report import AttentionExample

    for c in seed0:
        a = arrays[(c.stage, c.detector)]
        layers = [a[k] for k in sorted(a) if k.startswith("extra_attention_")]
        if not layers:
            continue
        maps = np.stack(layers, axis=2)  # (n_examples, C, layers, heads, L, L)
        kinds = a["kind"][a["example_index"]]
        j = int(np.argmax(kinds == 2)) if (kinds == 2).any() else 0
        test = dataset(store.cache, c.stage, c.seed, preset.n_test, "test")
        assert test.channel is not None and test.kind is not None and test.mask is not None
        i = int(a["example_index"][j])
        ch = int(test.channel[i])
        kind = "local deviation" if test.kind[i] == 2 else "spike"
        return AttentionExample(
            x=test.X[i], mask=test.mask[i], point=a["example_point"][j],
            attention=maps[j, ch].mean(axis=(0, 1)),  # mean over layers and heads
            title=f"stage {c.stage}, test window {i}: {kind} on channel {ch}")
    return None
