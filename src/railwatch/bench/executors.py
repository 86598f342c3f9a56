"""Executors: where the cells of a grid run. Each yields ``(cell, record, arrays)`` as cells
finish; only the driver writes results."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from railwatch.bench.cell import Cell, run_cell
from railwatch.bench.presets import Preset

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
