"""The command that runs the benchmark: ``bench``."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import click

from railwatch.cli.common import info, int_list
from railwatch.errors import RailwatchError


@click.command()
@click.option("--preset", default="quick", show_default=True, metavar="NAME|FILE",
              help="smoke (seconds, for tests), quick (all 8 stages x all detectors in ~10 min), "
                   "standard (the paper's sizes, 3 seeds, <= 2 h), or your own YAML file.")
@click.option("--out", type=click.Path(path_type=Path, file_okay=False), required=True,
              help="Output folder; finished cells are kept there, so a second run resumes.")
@click.option("--stages", help="Only these stages, e.g. 1,3,7.")
@click.option("--detectors", "detector_names",
              help="Only these detectors, e.g. aft-attention,oracle.")
@click.option("--seeds", type=click.IntRange(min=1), help="Number of seeds (overrides the preset).")
@click.option("--executor", type=click.Choice(["local", "ray"]), default="local",
              show_default=True, help="Run cells in this process, or as Ray tasks.")
@click.option("--address", help="Ray cluster address (with --executor ray); default: start a "
                                 "local Ray on this machine.")
@click.option("--retime", is_flag=True,
              help="Run nothing new: measure the scoring times of the finished cells again from "
                   "their saved models (after a run on a busy machine), then rewrite the report "
                   "of every finished stage and detector in OUT (so --stages 1,3,5 --retime "
                   "re-times Table II's stages and keeps Table I whole).")
@click.pass_obj
def bench(obj: dict, preset: str, out: Path, stages: str | None, detector_names: str | None,
          seeds: int | None, executor: str, address: str | None, retime: bool) -> None:
    """Run the benchmark grid (stages x detectors x seeds); write the paper's tables and a report.

    \b
    Writes into OUT: results.json, table1.md/.csv (AUC per stage, with the paper's values and the
    oracle ceiling), table2.md (inference time), localization.md, figures (PNG) and report.html.
    Example:
      railwatch bench --preset quick --out runs/quick
      railwatch bench --preset smoke --out runs/smoke --stages 1,7 --detectors cnn-ae,oracle
    """
    from railwatch.bench.cell import cells
    from railwatch.bench.grid import finished_grid, run_grid, write_run_report
    from railwatch.bench.grid import retime as retime_cells
    from railwatch.bench.presets import load_preset
    from railwatch.bench.store import ResultStore

    if retime and executor != "local":
        raise RailwatchError("--retime measures on this machine: leave out --executor")
    if address and executor != "ray":
        raise RailwatchError("--address goes with --executor ray")
    names = tuple(d.strip() for d in detector_names.split(",")) if detector_names else None
    p = load_preset(preset, stages=int_list(stages, "--stages"), detectors=names, seeds=seeds)
    if out.exists() and not out.is_dir():
        raise RailwatchError(f"--out {out} is a file: give a folder for the run")
    out.mkdir(parents=True, exist_ok=True)
    total = len(cells(p))
    started = time.perf_counter()
    from railwatch.progress import Progress

    # A line per finished cell without a terminal (make run > log), a bar on one.
    bar = Progress(total, "bench", "cells", enabled=obj["progress"], every_s=0.0)
    reused = 0

    def on_cell(cell: Any, record: dict[str, Any] | None, done: int, n: int) -> None:
        nonlocal reused
        if record is None:
            reused += 1
        else:
            bar.set_postfix_str(f"{cell.key} AUC {record['auc_instance']:.3f}")
        bar.update(1, timed=record is not None)

    store = ResultStore(out)
    with store.lock(), bar:  # one run at a time in OUT, its report included
        if retime:
            bar.set_description("retime")
            count = retime_cells(p, out, on_cell=lambda *_: bar.update(1))
            reused = total - count
            p = finished_grid(load_preset(preset, seeds=seeds), out, p)
            records = run_grid(p, out)  # every cell is finished: this only reads them
        else:
            records = run_grid(p, out, executor=executor, address=address, on_cell=on_cell)
        bar.close()
        report = write_run_report(out, p, records, wall_s=time.perf_counter() - started)
    if obj["progress"]:
        _summary(records, p.detectors)
    info(f"{total} cells ({reused} reused from an earlier run) in "
         f"{(time.perf_counter() - started) / 60:.1f} min")
    click.echo(f"report: {report}")


def _summary(records: list[dict[str, Any]], detectors: tuple[str, ...]) -> None:
    """One screen: instance AUC per stage x detector (mean over seeds)."""
    from railwatch.report.tables import aggregate, mean_std

    agg = aggregate(records, "auc_instance")
    stages = sorted({int(r["stage"]) for r in records})
    present = [d for d in detectors if any((s, d) in agg for s in stages)]
    width = max(len(d) for d in present)
    click.echo(f"\n{'auc_instance':<{width}}  " + "  ".join(f"  s{s}" for s in stages))
    for d in present:
        cells_ = [mean_std(agg.get((s, d), []))[0] for s in stages]
        click.echo(f"{d:<{width}}  " + "  ".join(
            "   – " if math.isnan(m) else f"{m:.3f}" for m in cells_))
