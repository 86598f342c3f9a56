"""The ``railwatch`` command line. Thin: it parses arguments, calls the library, and is the only
place that talks to the terminal. Every failure ends in one line on stderr and a non-zero exit.
"""

from __future__ import annotations

import json
import logging
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import click
import numpy as np

from railwatch import __version__
from railwatch.errors import RailwatchError, one_line

log = logging.getLogger("railwatch")


def info(message: str) -> None:
    """A status line for the user on stderr, unless --quiet."""
    ctx = click.get_current_context(silent=True)
    if ctx is None or (ctx.find_root().obj or {}).get("progress", True):
        click.echo(message, err=True)

STAGE_TABLE = """\b
  stage  channels  adds
  1      1         sinusoid + white noise (3 random variables)
  2      1         phase-continuous speed change at t_change (6)
  3      2         two channels, phase offsets (14)
  4      2         noise std steps up at t_noisechange (18)
  5      6         axle / bogie / body groups with their own ranges (54)
  6      6         anomalous channel drawn from kind-specific odds (54)
  7      6         one high-frequency burst on every channel (84)
  8      6         periodic truncated-Gaussian impulses (102)"""


def writable_file(path: Path) -> Path:
    """Fail early, in one line, if ``path`` cannot be written (before any long work)."""
    parent = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise RailwatchError(f"{path} is a directory: give a file name, e.g. {path}/out.npz")
    if not parent.is_dir():
        raise RailwatchError(
            f"cannot write {path}: folder {parent} does not exist (create it first)")
    if not os.access(parent, os.W_OK):
        raise RailwatchError(f"cannot write {path}: folder {parent} is not writable")
    return path


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="railwatch")
@click.option("-q", "--quiet", is_flag=True, help="No progress bars or log lines.")
@click.pass_context
def cli(ctx: click.Context, quiet: bool) -> None:
    """railwatch: find small transient rail defects in onboard accelerometer data, unsupervised.

    \b
    Generate the 8-stage synthetic benchmark, draw its example figure:
      railwatch generate --stage 7 --n 3000 --seed 0 --out stage7.npz
      railwatch figure stages --out stages.png
    Train a detector without labels, score and evaluate:
      railwatch detectors
      railwatch train --detector aft-attention --data train.npz --out model/
      railwatch score --model model/ --data test.npz --out scores.npz
      railwatch evaluate --data test.npz --scores scores.npz

    Run any command with --help for its options.
    """
    ctx.obj = {"progress": not quiet}
    logging.basicConfig(level=logging.WARNING if quiet else logging.INFO,
                        format="%(message)s", stream=sys.stderr)


@cli.command(epilog=STAGE_TABLE)
@click.option("--stage", "stage_number", type=click.IntRange(1, 8), required=True,
              help="Benchmark stage, 1-8 (table below).")
@click.option("--n", type=click.IntRange(min=1), default=1000, show_default=True,
              help="Number of windows. Exactly round(0.1 n) are anomalous, half of them spikes.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed; the same seed, stage and n give bit-identical output.")
@click.option("--out", type=click.Path(path_type=Path, dir_okay=False), required=True,
              help="Output .npz file (written atomically; loads with plain numpy.load).")
@click.option("--components", is_flag=True,
              help="Also store the nuisance signal and per-sample noise std (for the oracle).")
@click.option("--fs", type=click.FloatRange(min=0, min_open=True), default=100.0,
              show_default=True,
              help="Sampling rate in Hz. 2000 gives field-rate data: the same signals 20x finer.")
@click.option("--duration", type=click.FloatRange(min=0.2), default=2.0, show_default=True,
              help="Window length in seconds.")
@click.option("--bernoulli", is_flag=True,
              help="Draw each window anomalous with probability 0.1 instead of exactly 10 %.")
@click.pass_obj
def generate(obj: dict, stage_number: int, n: int, seed: int, out: Path, components: bool,
             fs: float, duration: float, bernoulli: bool) -> None:
    """Generate one labelled set of a benchmark stage into an .npz file.

    \b
    The file holds X (n, T, C) float32 windows, y (n,) instance labels, mask (n, T, C) true where
    an anomaly was added, kind (n,) 0 normal / 1 spike / 2 local deviation, channel (n,) the
    anomalous channel or -1, every sampled parameter as param_<name>, and meta, a JSON string
    (stage, seed, fs, channel names and groups, spec version, parameter keys).
    """
    from railwatch.synthetic import generate as generate_set

    writable_file(out)
    started = time.perf_counter()
    data = generate_set(stage_number, n, seed, fs=fs, duration=duration,
                        exact_rate=not bernoulli, components=components,
                        progress=obj["progress"])
    data.save(out)
    info(f"wrote {out}: stage {stage_number}, X {data.X.shape}, {int(data.y.sum())} anomalous "
         f"({int((data.kind == 1).sum())} spikes), {time.perf_counter() - started:.1f} s")


@cli.group()
def figure() -> None:
    """Draw figures (PNG)."""


@figure.command("stages")
@click.option("--out", type=click.Path(path_type=Path, dir_okay=False), required=True,
              help="Output PNG file.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the example windows.")
def figure_stages(out: Path, seed: int) -> None:
    """The paper's Figure 1: one anomalous window of each of the 8 stages.

    The anomaly is red, speed changes dashed green, noise steps dotted purple, HF bursts shaded
    orange, impulse onsets triangles; each title gives the number of random variables.
    """
    from railwatch.evaluation.figures import save_figure, stages_figure

    writable_file(out)
    save_figure(stages_figure(seed), out)
    info(f"wrote {out}")


# ----------------------------------------------------------------------------- detectors
@cli.command("detectors")
def list_detectors() -> None:
    """List the detectors: the registry name (what --detector takes), then what it is."""
    from railwatch.detectors.registry import REGISTRY

    width = max(map(len, REGISTRY))
    for name, entry in REGISTRY.items():
        click.echo(f"{name:<{width}}  {entry.description}")


def read_overrides(config: Path | None, settings: tuple[str, ...]) -> dict[str, Any]:
    """Config overrides from a YAML/TOML file, then ``--set key=value`` pairs (which win)."""
    from railwatch.mapping_files import read_mapping

    values: dict[str, Any] = {}
    if config is not None:
        values.update(read_mapping(config, "config"))
    for item in settings:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise RailwatchError(f"--set expects key=value, got {item!r} (e.g. --set epochs=5)")
        values[key.strip()] = value.strip()
    return values


def model_dir(path: Path) -> Path:
    """Fail early if ``path`` cannot become a model directory."""
    if path.exists() and not path.is_dir():
        raise RailwatchError(f"--out {path} is a file: give a folder name for the model")
    from railwatch.detectors.model_folder import is_model_folder

    if path.is_dir() and any(path.iterdir()) and not is_model_folder(path):
        raise RailwatchError(f"--out {path} is a non-empty folder that is not a railwatch model: "
                             "choose a new folder")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise RailwatchError(f"cannot write {path}: folder {parent} does not exist")
    return path


def _rate(value: str) -> float | None:
    if value.strip().lower() in ("none", "0", "off"):
        return None
    try:
        rate = float(value)
    except ValueError:
        raise RailwatchError(f"--resample takes a rate in Hz or 'none', got {value!r}") from None
    if rate <= 0:
        raise RailwatchError(f"--resample must be positive, got {value}")
    return rate


def _progress_seconds(total_s: float, desc: str) -> Any:
    """Progress counting seconds of recording: a bar on a terminal, a log line every 10 s
    elsewhere (hidden with -q)."""
    from railwatch.progress import Progress

    ctx = click.get_current_context()
    return Progress(round(total_s, 1), desc, "s of recording", every_s=10.0,
                    enabled=(ctx.find_root().obj or {}).get("progress", True), unit_scale=True,
                    bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s of recording "
                               "[{elapsed}<{remaining}]")


@cli.command(epilog="""\b
Recordings: --recordings takes one or more CSV, Parquet, HDF5 or .mat files (shell globs work)
and --layout a TOML/YAML file naming the channel columns, their sensor groups and the rate:
  fs = 2000.0
  time = "t"             # optional; speed = "v" and position = "x" too
  [channels]
  axle_left = "axle"     # column = sensor group, in the model's channel order
  ...
They are resampled (2000 -> 100 Hz by default), cut into 2-s windows every 1 s and trained on
without labels; the model folder keeps the layout, the preparation and an event threshold
for 'railwatch detect'.""")
@click.option("--detector", "name", required=True, metavar="NAME",
              help="Registry name (see 'railwatch detectors'), e.g. aft-attention.")
@click.option("--data", type=click.Path(path_type=Path),
              help="Training windows: an .npz with X (n, T, C); labels in it are never used.")
@click.option("--recordings", "recordings", multiple=True, type=click.Path(path_type=Path),
              metavar="PATH...", help="Train on recordings instead of windows (needs --layout).")
@click.argument("more_recordings", nargs=-1, type=click.Path(path_type=Path))
@click.option("--layout", "layout_file", type=click.Path(path_type=Path),
              help="Recording layout (TOML/YAML): columns, groups, rate, time/speed/position.")
@click.option("--resample", default="100", show_default=True, metavar="HZ|none",
              help="Rate the model works at, at most the recording's (2048 -> 100 Hz is 25/512).")
@click.option("--window", "window_s", type=float, default=2.0, show_default=True,
              help="Window length in seconds (recordings).")
@click.option("--hop", "hop_s", type=float, default=1.0, show_default=True,
              help="Seconds between training windows (recordings).")
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="Model folder to write (replaced only when training succeeded).")
@click.option("--config", "config_file", type=click.Path(path_type=Path),
              help="YAML or TOML file of config overrides (unknown keys are an error).")
@click.option("--set", "settings", multiple=True, metavar="KEY=VALUE",
              help="Override one config value, e.g. --set epochs=5 --set seed=1. Repeatable.")
@click.pass_obj
def train(obj: dict, name: str, data: Path | None, recordings: tuple[Path, ...],
          more_recordings: tuple[Path, ...], layout_file: Path | None, resample: str,
          window_s: float, hop_s: float, out: Path, config_file: Path | None,
          settings: tuple[str, ...]) -> None:
    """Train a detector, without labels, on a window file or on recordings, and save it.

    \b
    Examples:
      railwatch generate --stage 1 --n 2000 --seed 0 --out train.npz
      railwatch train --detector aft-attention --data train.npz --out model/ --set epochs=10
      railwatch train --detector aft-attention --recordings runs/*.parquet \\
          --layout layout.toml --out model/
    """
    from railwatch.detectors import create

    paths = recordings + more_recordings
    if more_recordings and not recordings:
        raise RailwatchError(f"unexpected argument {more_recordings[0]}: recordings go after "
                             "--recordings")
    if (data is None) == (not paths):
        raise RailwatchError("give either --data WINDOWS.npz or --recordings FILE... --layout "
                             "LAYOUT")
    overrides = {"progress": obj["progress"], **read_overrides(config_file, settings)}
    detector = create(name, overrides)
    model_dir(out)
    started = time.perf_counter()
    if data is not None:
        from railwatch.windows import load_windows

        windows = load_windows(data)
        detector.fit(windows.X, windows.components)
        detector.save(out)
        info(f"trained {name} on {len(windows.X):,} windows {windows.X.shape[1:]} in "
             f"{time.perf_counter() - started:.1f} s; threshold {detector.threshold_:.4g}; "
             f"saved to {out}")
        return
    from railwatch.recordings.layout import load_layout
    from railwatch.recordings.pipeline import null_threshold, recording_info, training_windows
    from railwatch.recordings.prepare import Preparation
    from railwatch.recordings.readers import Recording

    if layout_file is None:
        raise RailwatchError("--recordings needs --layout FILE (TOML/YAML naming the columns; "
                             "see 'railwatch train --help')")
    layout = load_layout(layout_file)
    prep = Preparation(rate=_rate(resample), window_s=window_s, train_hop_s=hop_s,
                       detect_hop_s=min(Preparation.detect_hop_s, window_s))
    prep.check(layout.fs)  # fail now, not at detection, on an impossible rate, window or hop
    sources = [Recording(p, layout) for p in paths]  # every file checked before any reading
    total = sum(r.duration_s for r in sources)
    with _progress_seconds(total, "reading") as bar:
        X = training_windows(sources, prep,
                             progress=lambda n: bar.update(round(n / layout.fs, 3)))
    if obj["progress"]:
        info(f"{len(X):,} windows of {X.shape[1]} samples x {X.shape[2]} channels from "
             f"{len(paths)} recording(s), {total / 60:.1f} min; training {name}")
    detector.fit(X)
    threshold = null_threshold(detector.decision_scores_)
    detector.save(out, extra_files=recording_info(layout, prep, threshold))
    info(f"trained {name} in {time.perf_counter() - started:.1f} s; event threshold "
         f"{threshold:.4g}; saved to {out}")


@cli.command()
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
    Every 2-s window (every 0.5 s) is scored; each sample takes the highest score of the windows
    that cover it; runs above the threshold (closer than 0.5 s merged) are events. Streams the
    file block by block: hours of recording in bounded memory.
    Example:
      railwatch detect --model model/ --recording run.parquet --out events.csv --plot run.png
    """
    from railwatch.evaluation.figures import plot_detection
    from railwatch.recordings import pipeline
    from railwatch.recordings.layout import load_layout
    from railwatch.recordings.readers import Recording

    if out.suffix.lower() not in (".csv", ".json"):
        raise RailwatchError(f"--out {out.name}: write events to a .csv or .json file")
    writable_file(out)
    if plot is not None:
        writable_file(plot)
    rm = pipeline.load_recording_model(model)
    layout = load_layout(layout_file) if layout_file else rm.layout
    rec = Recording(recording, layout)
    marks = _truth_times(truth) if truth else None
    started = time.perf_counter()
    with _progress_seconds(rec.duration_s, "detect") as bar:
        result = pipeline.detect(rm.detector, rec, rm.preparation,
                                 rm.threshold if threshold is None else threshold,
                                 progress=lambda n: bar.update(round(n / layout.fs, 3)))
    elapsed = time.perf_counter() - started
    pipeline.write_events(out, result.events)
    if plot is not None:
        title = (f"{recording.name}: {len(result.events)} events in "
                 f"{rec.duration_s / 60:.1f} min")
        plot_detection(result, plot, title=title, truth=marks)
    info(f"{len(result.events)} events in {rec.duration_s / 60:.1f} min of recording, scanned in "
         f"{elapsed:.1f} s ({rec.duration_s / max(elapsed, 1e-9):.0f}x real time); wrote {out}"
         + (f" and {plot}" if plot else ""))


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


@cli.command()
@click.option("--model", type=click.Path(path_type=Path), required=True,
              help="Model folder written by 'railwatch train'.")
@click.option("--out", type=click.Path(path_type=Path, dir_okay=False), required=True,
              help="ONNX file to write (network + statistics + recording layout, one file).")
def export(model: Path, out: Path) -> None:
    """Export a trained deep detector to ONNX, for onnxruntime onboard.

    \b
    The file holds the network (normalised windows -> raw outputs, dynamic batch) and, as
    metadata, everything else scoring needs. In Python:
      from railwatch.deploy.onnx import load_onnx
      det = load_onnx("model.onnx")      # scores like the PyTorch model (within 1e-3)
    Example:
      railwatch export --model model/ --out model.onnx
    """
    from railwatch.deploy.onnx import export_onnx, load_onnx

    if out.suffix.lower() != ".onnx":
        raise RailwatchError(f"--out {out.name}: give a file name ending in .onnx")
    writable_file(out)
    started = time.perf_counter()
    export_onnx(model, out)
    try:
        load_onnx(out)  # fails now, not onboard, if the file does not load
    except RailwatchError:
        out.unlink(missing_ok=True)  # no file that looks exported but does not load
        raise
    info(f"exported {model} to {out} ({out.stat().st_size / 1e6:.2f} MB) in "
         f"{time.perf_counter() - started:.1f} s")


@cli.command("generate-run")
@click.option("--minutes", type=float, default=10.0, show_default=True,
              help="Length of the run.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--fs", type=float, default=2000.0, show_default=True, help="Sampling rate (Hz).")
@click.option("--defect-every", "every_s", type=float, default=10.0, show_default=True,
              help="Mean seconds between defects.")
@click.option("--stage", type=click.IntRange(5, 8), default=5, show_default=True,
              help="Benchmark stage carried into continuous time: 5 signals and changing noise, "
                   "6 + channel odds by defect kind, 7 + HF bursts at rough spots of the track, "
                   "8 + wheel-periodic impulses.")
@click.option("--loud-stretches", is_flag=True,
              help="Rough sections of track (200-1500 m, 4 in 10) with 2-4x the noise.")
@click.option("--out", type=click.Path(path_type=Path, dir_okay=False), required=True,
              help="Recording file: .csv, .parquet, .h5 or .mat (the extension picks).")
@click.pass_obj
def generate_run(obj: dict, minutes: float, seed: int, fs: float, every_s: float, stage: int,
                 loud_stretches: bool, out: Path) -> None:
    """Synthesise a long six-channel field-rate run with defects at known times and positions.

    \b
    Writes OUT, OUT's layout (<name>.layout.toml) and the true defects (<name>.defects.csv).
    Stage-5 signals (axle, bogie, body groups) with a speed profile and changing noise; defects
    one every 10 s on average: spikes of +-3-4, local deviations of +-1.5-2 (0.05-0.2 s).
    --stage 7 and 8 add the later stages' nuisance, tied to the track and the wheels;
    --loud-stretches makes the noise level of whole sections of track change.
    Examples:
      railwatch generate-run --minutes 10 --seed 1 --out train1.parquet
      railwatch generate-run --stage 8 --loud-stretches --seed 4 --out rough.parquet
    """
    import csv

    from railwatch.atomic import atomic_path
    from railwatch.recordings.layout import layout_toml
    from railwatch.recordings.readers import FORMATS, write_recording
    from railwatch.synthetic.runs import DEFECT_FIELDS, Run, synthesize_run

    if out.suffix.lower() not in FORMATS:
        raise RailwatchError(f"--out {out.name}: use .csv, .parquet, .h5 or .mat")
    if minutes <= 0 or every_s <= 0:
        raise RailwatchError("--minutes and --defect-every must be positive")
    if fs < 100:
        raise RailwatchError(f"--fs must be at least 100 Hz (a spike lasts 0.01 s), got {fs:g}")
    writable_file(out)
    run = synthesize_run(minutes * 60, seed=seed, fs=fs, defect_every_s=every_s, stage=stage,
                         loud_stretches=loud_stretches)
    stem = out.with_suffix("")
    layout_path, truth_path = Path(f"{stem}.layout.toml"), Path(f"{stem}.defects.csv")
    with atomic_path(layout_path) as tmp:
        tmp.write_text(layout_toml(Run.layout(fs)))
    with atomic_path(truth_path) as tmp, open(tmp, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=DEFECT_FIELDS, lineterminator="\n")
        writer.writeheader()
        writer.writerows(run.defects)
    write_recording(out, run.columns())
    info(f"wrote {minutes:g} min at {fs:g} Hz with {len(run.defects)} defects: {out}, "
         f"{layout_path}, {truth_path}")


@cli.command()
@click.option("--model", type=click.Path(path_type=Path), required=True,
              help="Model folder written by 'railwatch train'.")
@click.option("--data", type=click.Path(path_type=Path), required=True,
              help="Windows to score: an .npz with X (n, T, C), same channels as in training.")
@click.option("--out", type=click.Path(path_type=Path, dir_okay=False), required=True,
              help="Output .npz: instance (n,), point (n, T), channel (n, T, C), threshold, "
                   "and the localised time_index/channel_index of each window.")
def score(model: Path, data: Path, out: Path) -> None:
    """Score windows with a trained detector (higher = more anomalous)."""
    from railwatch.detectors import load_detector
    from railwatch.scoring.reduce import localize
    from railwatch.synthetic.datasets import atomic_savez
    from railwatch.windows import load_windows

    writable_file(out)
    detector = load_detector(model)
    windows = load_windows(data)
    started = time.perf_counter()
    s = detector.score(windows.X, windows.components)
    loc = localize(s.point, s.channel, detector.config.fs)
    atomic_savez(out, {
        "instance": s.instance, "point": s.point, "channel": s.channel,
        "threshold": np.array(detector.threshold_), "time_index": loc.time_index,
        "channel_index": loc.channel, "detector": np.array(detector.registry_name),
    })
    flagged = int((s.instance > detector.threshold_).sum())
    info(f"scored {len(s.instance):,} windows in {time.perf_counter() - started:.2f} s: "
         f"{flagged} above the fitted threshold; wrote {out}")


@cli.command()
@click.option("--data", type=click.Path(path_type=Path), required=True,
              help="The labelled test set that was scored (from 'railwatch generate').")
@click.option("--scores", "scores_path", type=click.Path(path_type=Path), required=True,
              help="Scores written by 'railwatch score'.")
@click.option("--out", type=click.Path(path_type=Path, dir_okay=False),
              help="Also write the metrics as JSON.")
def evaluate(data: Path, scores_path: Path, out: Path | None) -> None:
    """Compute the metrics of the evaluation spec for scored, labelled windows.

    \b
    auc_instance  ROC-AUC of window scores (primary)     auc_point  ROC-AUC per time step
    auc_paper7    the paper's 7-threshold AUC            ap_instance  average precision
    f1_fitted     F1 at the threshold fitted in training  loc_time / loc_channel  localisation
    """
    from railwatch.detectors.api import Scores
    from railwatch.evaluation.metrics import evaluate_scores
    from railwatch.windows import load_windows

    if out is not None:
        writable_file(out)
    windows = load_windows(data)
    windows.require_labels(data)
    arrays = load_windows_like(scores_path, ("instance", "point", "channel", "threshold"))
    n = len(windows.X)
    if arrays["channel"].shape != windows.X.shape:
        raise RailwatchError(f"scores have shape {arrays['channel'].shape} but the data "
                             f"{windows.X.shape}: were they computed on {data}?")
    scores = Scores(instance=arrays["instance"], point=arrays["point"], channel=arrays["channel"])
    metrics = evaluate_scores(windows.labels["y"], windows.labels["mask"],
                              windows.labels["channel"], scores, float(arrays["threshold"]),
                              fs=float(windows.meta.get("fs", 100.0)))
    click.echo(f"{n:,} windows, {int(windows.labels['y'].sum()):,} anomalous")
    for key, value in metrics.items():
        click.echo(f"  {key:<13} {value:.4f}")
    if out is not None:
        from railwatch.atomic import atomic_path

        with atomic_path(out) as tmp:
            tmp.write_text(json.dumps(
                {k: (None if math.isnan(v) else v) for k, v in metrics.items()}, indent=2))
        info(f"wrote {out}")


def load_windows_like(path: Path, keys: tuple[str, ...]) -> dict[str, Any]:
    """Read named arrays from an .npz with one-line errors."""
    if not path.is_file():
        raise RailwatchError(f"no such file: {path}")
    try:
        with np.load(path, allow_pickle=False) as f:
            missing = [k for k in keys if k not in f.files]
            if missing:
                raise RailwatchError(f"{path} lacks {', '.join(missing)}: is it a scores file "
                                     "from 'railwatch score'?")
            return {k: f[k] for k in keys}
    except RailwatchError:
        raise
    except Exception as e:  # noqa: BLE001
        raise RailwatchError(f"cannot read {path}: {one_line(e)[:160]}") from None


# ----------------------------------------------------------------------------- bench
def _int_list(value: str | None, what: str) -> tuple[int, ...] | None:
    if value is None:
        return None
    try:
        return tuple(int(v) for v in value.split(",") if v.strip())
    except ValueError:
        raise RailwatchError(f"{what} takes numbers separated by commas, e.g. 1,3,7") from None


@cli.command()
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
                   "their saved models (after a run on a busy machine), then rewrite the report.")
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
    from railwatch.bench.outputs import write_report
    from railwatch.bench.presets import load_preset
    from railwatch.bench.run import ResultStore, cells, run_grid

    if retime and executor != "local":
        raise RailwatchError("--retime measures on this machine: leave out --executor")
    if address and executor != "ray":
        raise RailwatchError("--address goes with --executor ray")
    names = tuple(d.strip() for d in detector_names.split(",")) if detector_names else None
    p = load_preset(preset, stages=_int_list(stages, "--stages"), detectors=names, seeds=seeds)
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
            from railwatch.bench.run import retime as retime_cells

            missing = [c.key for c in cells(p) if not store.done(p, c)]
            if missing:
                raise RailwatchError(f"{len(missing)} cells of this grid are not finished (e.g. "
                                     f"{missing[0]}): run without --retime first")
            bar.set_description("retime")
            count = retime_cells(p, out, on_cell=lambda *_: bar.update(1))
            reused = total - count
            records = run_grid(p, out)  # every cell is finished: this only reads them
        else:
            records = run_grid(p, out, executor=executor, address=address, on_cell=on_cell)
        bar.close()
        report = write_report(out, p, records, wall_s=time.perf_counter() - started)
    if obj["progress"]:
        _summary(records, p.detectors)
    info(f"{total} cells ({reused} reused from an earlier run) in "
         f"{(time.perf_counter() - started) / 60:.1f} min")
    click.echo(f"report: {report}")


def _summary(records: list[dict[str, Any]], detectors: tuple[str, ...]) -> None:
    """One screen: instance AUC per stage x detector (mean over seeds)."""
    from railwatch.evaluation.tables import aggregate, mean_std

    agg = aggregate(records, "auc_instance")
    stages = sorted({int(r["stage"]) for r in records})
    present = [d for d in detectors if any((s, d) in agg for s in stages)]
    width = max(len(d) for d in present)
    click.echo(f"\n{'auc_instance':<{width}}  " + "  ".join(f"  s{s}" for s in stages))
    for d in present:
        cells_ = [mean_std(agg.get((s, d), []))[0] for s in stages]
        click.echo(f"{d:<{width}}  " + "  ".join(
            "   – " if math.isnan(m) else f"{m:.3f}" for m in cells_))


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the CLI, turning every error into one line and an exit code."""
    try:
        rv = cli.main(args=argv, prog_name="railwatch", standalone_mode=False)
        return rv if isinstance(rv, int) else 0
    except click.exceptions.NoArgsIsHelpError as e:
        click.echo(e.ctx.get_help() if e.ctx else str(e))
        return 0
    except click.UsageError as e:
        where = f" (see '{e.ctx.command_path} --help')" if e.ctx else ""
        click.echo(f"railwatch: error: {e.format_message()}{where}", err=True)
        return 2
    except click.ClickException as e:
        click.echo(f"railwatch: error: {e.format_message()}", err=True)
        return e.exit_code
    except click.exceptions.Abort:
        click.echo("railwatch: aborted", err=True)
        return 130
    except (RailwatchError, ValueError, OSError) as e:
        if os.environ.get("RAILWATCH_DEBUG"):
            raise
        click.echo(f"railwatch: error: {one_line(e)}", err=True)
        return 1
    except Exception as e:  # noqa: BLE001 - the user gets one line, the debug flag the traceback
        if os.environ.get("RAILWATCH_DEBUG"):
            raise
        click.echo(f"railwatch: internal error: {type(e).__name__}: {one_line(e)} "
                   "(set RAILWATCH_DEBUG=1 for the traceback and please report it)", err=True)
        return 1


if __name__ == "__main__":
    sys.exit(main())
