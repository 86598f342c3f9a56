"""Executors: where the cells of a grid run. Each yields ``(cell, record, arrays)`` as cells
finish; only the driver writes results."""

from __future__ import annotations

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
    """Every cell a Ray task (one CPU each, :func:`railwatch.parallel.ray_imap`), yielded as
    they finish.

    ``address`` joins an existing cluster; without it a local Ray starts on this machine. Tasks
    generate their data themselves (deterministically, cached on their node's disk under the same
    path) and send back records and small arrays; only the driver writes results.
    """
    from railwatch.parallel import ray_imap

    for cell, (record, arrays) in ray_imap(_ray_cell, todo, (preset, str(cache)), address):
        yield cell, record, arrays


def _ray_cell(cell: Cell, preset: Preset, cache: str) -> tuple[dict[str, Any], dict[str, Any]]:
    return run_cell(cell, preset, Path(cache))
