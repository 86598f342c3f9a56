"""The command that scans recordings: ``detect``."""

from __future__ import annotations

import time
from pathlib import Path

import click

from railwatch.cli.common import info, progress_seconds, writable_file
from railwatch.errors import RailwatchError


@click.command()
@click.option("--model", type=click.Path(path_type=Path), required=True,
              help="Model folder written by 'railwatch train --recordings'.")
@click.option("--recording", type=click.Path(path_type=Path), required=True,
              help="Recording to scan: CSV, Parquet, HDF5 or .mat.")
@click.option("--out", type=click.Path(path_type=Path, dir_okay=False), required=True,
              help="Events file: .csv (a row per event) or .json.")
@click.option("--layout", "layout_file", type=click.Path(path_type=Path),
              help="Layout of this recording if its columns differ from the training layout "
                   "(same channel count and order).")
@click.option("--plot", type=click.Path(path_type=Path, dir_okay=False),
              help="Also draw the score along time (and track position) with events, as PNG.")
@click.option("--threshold", type=float,
              help="Event threshold instead of the one fitted in training.")
@click.option("--truth", type=click.Path(path_type=Path),
              help="CSV of known defects (a 'center_s' or 'time_s' column) to mark on the plot.")
@click.pass_obj
def detect(obj: dict, model: Path, recording: Path, out: Path, layout_file: Path | None,
           plot: Path | None, threshold: float | None, truth: Path | None) -> None:
    """Scan a recording for defects: events with start, end, peak time, channel and position.

    \b
    The recording is prepared as the model was trained (its rate, window and hop are in the
    model folder: about 10 m of track per window at field scale, 2-s windows every 0.5 s at
    the benchmark's); each sample takes the highest score of the windows that cover it; runs
    above the threshold (closer than 0.5 s merged) are events. Streams the file block by
    block: hours of recording in bounded memory.
    Example:
      railwatch detect --model model/ --recording run.parquet --out events.csv --plot run.png
    """
    from railwatch.detection import pipeline
    from railwatch.recordings.layout import load_layout
    from railwatch.recordings.readers import Recording

    if out.suffix.lower() not in (".csv", ".json"):
        raise RailwatchError(f"--out {out.name}: write events to a .csv or .json file")
    writable_file(out)
    if plot is not None:
        writable_file(plot)
    rm = pipeline.load_recording_model(model)
    layout = rm.layout_for(load_layout(layout_file) if layout_file else None)
    rec = Recording(recording, layout)
    marks = _truth_times(truth) if truth else None
    started = time.perf_counter()
    with progress_seconds(rec.duration_s, "detect") as bar:
        result = pipeline.detect(rm.detector, rec, rm.preparation,
                                 rm.threshold if threshold is None else threshold,
                                 progress=lambda n: bar.update(round(n / layout.fs, 3)))
    elapsed = time.perf_counter() - started
    pipeline.write_events(out, result.events)
    if plot is not None:
        from railwatch.report.figures import plot_detection  # matplotlib: only for a plot

        title = (f"{recording.name}: {len(result.events)} events in "
                 f"{rec.duration_s / 60:.1f} min")
        plot_detection(result, plot, title=title, truth=marks)
    info(f"{len(result.events)} events in {rec.duration_s / 60:.1f} min of recording, scanned in "
         f"{elapsed:.1f} s ({rec.duration_s / max(elapsed, 1e-9):.0f}x real time); wrote {out}"
         + (f" and {plot}" if plot else ""))
    if rm.preparation.wheel_turns:
        combed = ", ".join(f"{c} {t:.2f} m" for c, t in result.wheel_turns.items())
        info(f"wheel comb: {combed or 'no channel with a clear wheel turn, none combed'}")


def _truth_times(path: Path) -> list[float]:
    import csv

    if not path.is_file():
        raise RailwatchError(f"no such file: {path}")
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        key = next((k for k in ("center_s", "time_s") if k in (reader.fieldnames or [])), None)
        if key is None:
            raise RailwatchError(f"{path} needs a 'center_s' or 'time_s' column of defect times")
        try:
            return [float(r[key]) for r in reader]
        except (TypeError, ValueError):
            raise RailwatchError(f"{path}: column {key} must hold numbers of seconds") from None
