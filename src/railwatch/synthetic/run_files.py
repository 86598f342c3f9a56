"""Test recordings without real data: a synthesised run (:mod:`railwatch.synthetic.runs`) written
in a recording format (:mod:`railwatch.recordings.readers`), with its layout and its true defects
beside it."""

from __future__ import annotations

import os
from pathlib import Path

from railwatch.atomic import atomic_csv, atomic_path
from railwatch.errors import RailwatchError
from railwatch.recordings.layout import layout_toml
from railwatch.recordings.readers import FORMATS, write_recording
from railwatch.synthetic.runs import DEFECT_FIELDS, Run, Variation, synthesize_run


def check_run_settings(out: str | os.PathLike[str], minutes: float, every_s: float,
                       fs: float) -> None:
    """One-line errors for settings no run can have, before any work."""
    if Path(out).suffix.lower() not in FORMATS:
        raise RailwatchError(f"--out {Path(out).name}: use .csv, .parquet, .h5 or .mat")
    if minutes <= 0 or every_s <= 0:
        raise RailwatchError("--minutes and --defect-every must be positive")
    if fs < 100:
        raise RailwatchError(f"--fs must be at least 100 Hz (a spike lasts 0.01 s), got {fs:g}")


def write_run(out: str | os.PathLike[str], minutes: float, seed: int = 0, fs: float = 2000.0,
              every_s: float = 10.0, stage: int = 5, loud_stretches: bool = False,
              variation: Variation | None = None) -> tuple[Run, Path, Path]:
    """Synthesise a run (made differently with ``variation``) and write it to ``out`` (the
    extension picks the format), its layout to ``<stem>.layout.toml`` and its true defects to
    ``<stem>.defects.csv``; returns the run and the paths of the layout and of the defects."""
    check_run_settings(out, minutes, every_s, fs)
    run = synthesize_run(minutes * 60, seed=seed, fs=fs, defect_every_s=every_s, stage=stage,
                         loud_stretches=loud_stretches, variation=variation)
    return (run, *save_run(out, run))


def save_run(out: str | os.PathLike[str], run: Run) -> tuple[Path, Path]:
    """Write ``run`` to ``out`` (the extension picks the format), its layout to
    ``<stem>.layout.toml`` and its true defects to ``<stem>.defects.csv``; returns the paths of
    the layout and of the defects."""
    out = Path(out)
    stem = out.with_suffix("")
    layout_path, truth_path = Path(f"{stem}.layout.toml"), Path(f"{stem}.defects.csv")
    with atomic_path(layout_path) as tmp:
        tmp.write_text(layout_toml(Run.layout(run.fs)))
    atomic_csv(truth_path, DEFECT_FIELDS, run.defects)
    write_recording(out, run.columns())
    return layout_path, truth_path
