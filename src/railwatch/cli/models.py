"""Commands that train and apply a detector: ``detectors``, ``train``, ``score``, ``evaluate``
and ``export``."""

from __future__ import annotations

import time
from pathlib import Path

import click

from railwatch.cli.common import (
    info,
    model_dir,
    parse_rate,
    read_overrides,
    writable_file,
)
from railwatch.errors import RailwatchError


@click.command("detectors")
def list_detectors() -> None:
    """List the detectors: the registry name (what --detector takes), then what it is."""
    from railwatch.detectors.registry import REGISTRY

    width = max(map(len, REGISTRY))
    for name, entry in REGISTRY.items():
        click.echo(f"{name:<{width}}  {entry.description}")


@click.command(epilog="""\b
Recordings: --recordings takes one or more CSV, Parquet, HDF5 or .mat files (shell globs work)
and --layout a TOML/YAML file naming the channel columns, their sensor groups and the rate:
  fs = 2000.0
  time = "t"             # optional; speed = "v" and position = "x" too
  [channels]
  axle_left = "axle"     # column = sensor group, in the model's channel order
  ...
How they are prepared follows the layout's scale (docs/recordings.md):
  field (a real rail, the default)  the recording's rate kept, windows of 10 m of track at the
      median speed (0.5 s at 20 m/s), only the axle-box channels scored (group 'axle'):
      a 2-10 cm defect is crossed in 1-10 ms and rings the wheel at 50-1000 Hz
  benchmark (generate-run's runs)   resampled to 100 Hz, 2-s windows every 1 s, every channel:
      their defects are the benchmark's, twenty times longer (the paper's x20 scaling)
--resample, --window, --hop and --groups override the choice, which train prints. Training
uses no labels; the model folder keeps the layout of the scored channels, the preparation and
an event threshold for 'railwatch detect': the level that normal recording would cross in 0.1
windows per minute, by the training windows' null; --events-per-minute sets it.
--wheel-comb takes out, before resampling, impulses that repeat at every turn of a wheel (flat
or out-of-round wheels): each channel's turn is found in each recording (its cepstrum over
distance; channels without a clear one are left alone) and every sample loses the mean of the
samples 1 and 2 turns before and after it. It needs a position or speed
column; detect and scan then do the same to every recording.""")
@click.option("--detector", "name", required=True, metavar="NAME",
              help="Registry name (see 'railwatch detectors'), e.g. aft-attention.")
@click.option("--data", type=click.Path(path_type=Path),
              help="Training windows: an .npz with X (n, T, C); labels in it are never used.")
@click.option("--recordings", "recordings", multiple=True, type=click.Path(path_type=Path),
              metavar="PATH...", help="Train on recordings instead of windows (needs --layout).")
@click.argument("more_recordings", nargs=-1, type=click.Path(path_type=Path))
@click.option("--layout", "layout_file", type=click.Path(path_type=Path),
              help="Recording layout (TOML/YAML): columns, groups, rate, time/speed/position.")
@click.option("--resample", default="auto", show_default=True, metavar="auto|HZ|none",
              help="Rate the model works at, at most the recording's (2048 -> 100 Hz is 25/512); "
                   "auto: by the layout's scale (below).")
@click.option("--window", "window_s", type=click.FloatRange(min=0, min_open=True),
              help="Window length in seconds (recordings; default by the layout's scale).")
@click.option("--hop", "hop_s", type=click.FloatRange(min=0, min_open=True),
              help="Seconds between training windows (recordings; default half a window at "
                   "field scale, 1 s at the benchmark's).")
@click.option("--groups", "groups_text", default="auto", show_default=True,
              help="Sensor groups to score, comma-separated (recordings), or all; auto: the "
                   "axle boxes at field scale, every group at the benchmark's.")
@click.option("--wheel-comb", is_flag=True,
              help="Comb out wheel-periodic impulses before resampling (recordings with a "
                   "position or speed column; see below).")
@click.option("--events-per-minute", type=float, metavar="RATE",
              help="The event threshold: windows per minute of normal recording that would "
                   "cross it, by the training windows' null (recordings; default 0.1 at field "
                   "scale, 0.6 at the benchmark's). detect and scan --threshold override it.")
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="Model folder to write (replaced only when training succeeded).")
@click.option("--config", "config_file", type=click.Path(path_type=Path),
              help="YAML or TOML file of config overrides (unknown keys are an error).")
@click.option("--set", "settings", multiple=True, metavar="KEY=VALUE",
              help="Override one config value, e.g. --set epochs=5 --set seed=1. Repeatable.")
@click.pass_obj
def train(obj: dict, name: str, data: Path | None, recordings: tuple[Path, ...],
          more_recordings: tuple[Path, ...], layout_file: Path | None, resample: str,
          window_s: float | None, hop_s: float | None, groups_text: str, wheel_comb: bool,
          events_per_minute: float | None, out: Path,
          config_file: Path | None, settings: tuple[str, ...]) -> None:
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
    if events_per_minute is not None and data is not None:
        raise RailwatchError("--events-per-minute sets the event threshold of recordings: "
                             "train with --recordings FILE... --layout LAYOUT")
    if wheel_comb and data is not None:
        raise RailwatchError("--wheel-comb works on recordings (it needs the distance "
                             "travelled): train with --recordings FILE... --layout LAYOUT")
    overrides = {"progress": obj["progress"], **read_overrides(config_file, settings)}
    detector = create(name, overrides)  # unknown names and settings fail before any reading
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
    from railwatch.detection.pipeline import train_on_recordings
    from railwatch.recordings.layout import load_layout

    if layout_file is None:
        raise RailwatchError("--recordings needs --layout FILE (TOML/YAML naming the columns; "
                             "see 'railwatch train --help')")
    layout = load_layout(layout_file)
    rate = "auto" if resample.strip().lower() == "auto" else parse_rate(resample)
    chosen = None if groups_text.strip().lower() in ("auto", "") else (
        tuple(dict.fromkeys(layout.groups)) if groups_text.strip().lower() == "all" else
        tuple(g.strip() for g in groups_text.split(",") if g.strip()))
    done = train_on_recordings(name, overrides, paths, layout, out, rate=rate,
                               window_s=window_s, hop_s=hop_s, groups=chosen,
                               wheel_comb=wheel_comb, events_per_minute=events_per_minute,
                               say=info, progress=obj["progress"])
    info(f"trained {name} in {time.perf_counter() - started:.1f} s; event threshold "
         f"{done.threshold:.4g} ({done.per_minute:g} windows per minute of the training "
         f"recordings' null, --events-per-minute); saved to {out}")


@click.command()
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
    from railwatch.evaluation.scores_file import write_scores
    from railwatch.windows import load_windows

    writable_file(out)
    detector = load_detector(model)
    windows = load_windows(data)
    started = time.perf_counter()
    s = detector.score(windows.X, windows.components)
    write_scores(out, detector, s)
    flagged = int((s.instance > detector.threshold_).sum())
    info(f"scored {len(s.instance):,} windows in {time.perf_counter() - started:.2f} s: "
         f"{flagged} above the fitted threshold; wrote {out}")


@click.command()
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
    from railwatch.evaluation.scores_file import evaluate_files, write_metrics

    if out is not None:
        writable_file(out)
    windows, metrics = evaluate_files(data, scores_path)
    assert windows.y is not None
    click.echo(f"{len(windows.X):,} windows, {int(windows.y.sum()):,} anomalous")
    for key, value in metrics.items():
        click.echo(f"  {key:<13} {value:.4f}")
    if out is not None:
        write_metrics(out, metrics)
        info(f"wrote {out}")


@click.command()
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
    from railwatch.deploy.onnx import export_onnx

    if out.suffix.lower() != ".onnx":
        raise RailwatchError(f"--out {out.name}: give a file name ending in .onnx")
    writable_file(out)
    started = time.perf_counter()
    export_onnx(model, out)  # loads the file back: fails now, not onboard, if it does not load
    info(f"exported {model} to {out} ({out.stat().st_size / 1e6:.2f} MB) in "
         f"{time.perf_counter() - started:.1f} s")
