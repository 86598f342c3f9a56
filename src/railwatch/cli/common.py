"""What every command shares: status lines, early checks of output paths, config overrides,
progress over seconds of recording."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import click

from railwatch.errors import RailwatchError


def info(message: str) -> None:
    """A status line for the user on stderr, unless --quiet."""
    ctx = click.get_current_context(silent=True)
    if ctx is None or (ctx.find_root().obj or {}).get("progress", True):
        click.echo(message, err=True)


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


def parse_rate(value: str) -> float | None:
    if value.strip().lower() in ("none", "0", "off"):
        return None
    try:
        rate = float(value)
    except ValueError:
        raise RailwatchError(f"--resample takes a rate in Hz or 'none', got {value!r}") from None
    if rate <= 0:
        raise RailwatchError(f"--resample must be positive, got {value}")
    return rate


def progress_seconds(total_s: float, desc: str) -> Any:
    """Progress counting seconds of recording: a bar on a terminal, a log line every 10 s
    elsewhere (hidden with -q)."""
    from railwatch.progress import seconds_of_recording

    ctx = click.get_current_context()
    return seconds_of_recording(total_s, desc,
                                (ctx.find_root().obj or {}).get("progress", True))


def int_list(value: str | None, what: str) -> tuple[int, ...] | None:
    if value is None:
        return None
    try:
        return tuple(int(v) for v in value.split(",") if v.strip())
    except ValueError:
        raise RailwatchError(f"{what} takes numbers separated by commas, e.g. 1,3,7") from None
