"""The model folder: every file a saved detector consists of, written atomically, read checked.

A fitted detector is a folder (``railwatch train --out``)::

    detector.json   header: format, detector name, class, config, window shape, SHA-256 of the rest
    stats.npz       fitted arrays: input normalisation, score statistics, threshold
    weights.pt      the network's state_dict (deep detectors only)
    recording.json  layout, preparation and event threshold (models trained on recordings only)

This module owns those names and the folder's life cycle: :func:`write` replaces a folder only
when the new one is complete and flushed to disk, :func:`read_header` refuses a damaged or
foreign folder in one line, :func:`read_stats` and :func:`read_weights` read the rest. It knows no
detector class (:func:`railwatch.detectors.registry.load_detector` turns a folder into one) and
imports torch only to write or read weights. No pickled objects anywhere.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from railwatch.atomic import fsync_path, sha256_file
from railwatch.errors import RailwatchError, one_line

if TYPE_CHECKING:
    import torch

FORMAT = "railwatch-detector"
FORMAT_VERSION = 1
HEADER = "detector.json"
STATS = "stats.npz"
WEIGHTS = "weights.pt"
#: Written by ``railwatch train --recordings`` beside the model (:func:`recording_file`).
RECORDING = "recording.json"
#: The files :func:`write` writes itself (extra files are named by the caller).
MODEL_FILES = (HEADER, STATS, WEIGHTS)
#: ``detector.json`` key of the SHA-256 of every other file in the folder.
CHECKSUMS = "sha256"


def recording_file(info: Mapping[str, Any]) -> dict[str, str]:
    """The extra file of a model trained on recordings, for :func:`write`'s ``extra_files``:
    ``info`` (its layout, preparation and threshold rule, JSON-ready) as ``recording.json``."""
    return {RECORDING: json.dumps(info, indent=2)}


def read_recording(path: str | os.PathLike[str]) -> dict[str, Any] | None:
    """A model folder's ``recording.json`` (:func:`recording_file`); None for a model trained on
    windows. A damaged file is refused in one line."""
    file = Path(path) / RECORDING
    if not file.is_file():
        return None
    try:
        info = json.loads(file.read_text())
    except (OSError, ValueError) as e:
        raise RailwatchError(f"{file} is damaged ({one_line(e)}): train the model again") from None
    if not isinstance(info, dict):
        raise RailwatchError(f"{file} is damaged (not a table): train the model again")
    return info


def is_model_folder(path: Path) -> bool:
    """Whether ``path`` holds a saved model (its header)."""
    return (path / HEADER).is_file()


def write(path: str | os.PathLike[str], header: Mapping[str, Any],
          stats: Mapping[str, NDArray[Any]], state: Mapping[str, torch.Tensor] | None = None,
          extra_files: Mapping[str, str] | None = None) -> Path:
    """Write a model folder at ``path`` (replaced only when complete): ``header`` (JSON-ready,
    completed with the format and the checksums), ``stats``, the network ``state`` if any, and
    ``extra_files`` (name -> text, for example the recording layout), in one atomic step.

    The folder is written as ``.NAME.tmp-PID`` beside ``path``, every file and the folder
    flushed to disk (``fsync``), then swapped in: the old model, if any, is renamed to
    ``.NAME.old-PID``, the new one to ``path``, the old one deleted. A process killed at
    any point (or a power cut, as far as the file system keeps its ``fsync`` promises)
    leaves the old model or the new one at ``path``; killed between the two renames, it
    leaves no ``path`` but the previous model in ``.NAME.old-PID``, which :func:`read_header`
    points to. Leftovers of writers that are no longer running are removed by the next write.
    ``detector.json`` records the SHA-256 of every other file, so that a damaged or replaced
    file is refused when the model is read.
    """
    path = Path(path)
    if path.exists() and not is_model_folder(path) and any(path.iterdir()):
        raise RailwatchError(
            f"{path} exists and is not a railwatch model directory: choose a new folder"
        )
    if not path.parent.is_dir():
        raise RailwatchError(f"cannot write {path}: folder {path.parent} does not exist")
    for stale in stale_siblings(path, "tmp"):  # half-written by a killed save
        shutil.rmtree(stale, ignore_errors=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    old = path.with_name(f".{path.name}.old-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    moved = False
    try:
        for name, text in (extra_files or {}).items():
            if name in MODEL_FILES or Path(name).name != name or name.startswith("."):
                raise RailwatchError(f"cannot save an extra file named {name!r}")
            (tmp / name).write_text(text)
        np.savez(tmp / STATS, **stats)  # type: ignore[arg-type]
        if state is not None:
            import torch

            torch.save(dict(state), tmp / WEIGHTS)
        full = {"format": FORMAT, "format_version": FORMAT_VERSION, **header,
                CHECKSUMS: {p.name: sha256_file(p) for p in sorted(tmp.iterdir())}}
        (tmp / HEADER).write_text(json.dumps(full, indent=2))
        for p in tmp.iterdir():
            fsync_path(p)
        fsync_path(tmp)
        if path.exists():
            shutil.rmtree(old, ignore_errors=True)  # a dead namesake's, not ours
            os.rename(path, old)
            moved = True
        os.rename(tmp, path)
        moved = False
        fsync_path(path.parent)
    except BaseException:
        if moved and not path.exists():
            os.rename(old, path)  # put the old model back
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    shutil.rmtree(old, ignore_errors=True)
    for stale in stale_siblings(path, "old"):  # a previous model a killed save set aside
        shutil.rmtree(stale, ignore_errors=True)
    return path


def check_folder(path: Path) -> None:
    """One-line errors for a path that is no model folder at all (missing, or no header)."""
    if not path.is_dir():
        previous = [p for p in stale_siblings(path, "old") if is_model_folder(p)]
        if previous:
            raise RailwatchError(
                f"no model directory at {path}; a save that was interrupted left the previous "
                f"model in {previous[-1]}: rename it to {path.name} to use it, or train again")
        raise RailwatchError(f"no model directory at {path}")
    if not is_model_folder(path):
        raise RailwatchError(f"{path} is not a railwatch model directory (no {HEADER}): "
                             "give the folder written by 'railwatch train'")


def read_header(path: Path) -> dict[str, Any]:
    """The checked header of the model folder ``path`` (after :func:`check_folder`): the
    format, a version this railwatch reads, and every other file unchanged since it was saved.
    Raises :class:`RailwatchError` for a newer format or a damaged file, ``ValueError`` for a
    header that is not railwatch's."""
    header = json.loads((path / HEADER).read_text())
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise ValueError(f"{HEADER} is not a railwatch model header")
    version = header.get("format_version", 0)
    if not isinstance(version, int) or isinstance(version, bool):
        raise ValueError(f"{HEADER}: format_version {version!r} is not a number")
    if version > FORMAT_VERSION:
        raise RailwatchError(
            f"{path} was saved by a newer railwatch (format {version}, this one reads up "
            f"to {FORMAT_VERSION}): upgrade railwatch"
        )
    _verify_checksums(path, header)
    return header


def read_stats(path: Path) -> dict[str, NDArray[Any]]:
    """The fitted arrays of the model folder ``path``."""
    if not (path / STATS).is_file():
        raise RailwatchError(f"{STATS} is missing")
    try:
        with np.load(path / STATS, allow_pickle=False) as f:
            return {k: f[k] for k in f.files}
    except Exception as e:  # noqa: BLE001 - zip, npy or pickle errors alike
        raise RailwatchError(f"{STATS} is damaged ({type(e).__name__}: "
                             f"{one_line(e)[:120]})") from None


def read_weights(path: Path) -> dict[str, torch.Tensor] | None:
    """The network weights of the model folder ``path``, or None when it has none."""
    weights = path / WEIGHTS
    if not weights.exists():
        return None
    import torch

    try:
        return torch.load(weights, map_location="cpu", weights_only=True)  # type: ignore[no-any-return]
    except Exception as e:  # noqa: BLE001 - torch's message is about pickle safety
        raise RailwatchError(f"{WEIGHTS} is damaged or holds no network weights "
                             f"({type(e).__name__})") from None


def _verify_checksums(path: Path, header: dict[str, Any]) -> None:
    """Every file listed in ``detector.json`` present and unchanged (models saved before
    checksums were recorded list none)."""
    sums = header.get(CHECKSUMS)
    if sums is None:
        return
    if not isinstance(sums, dict):
        raise ValueError(f"{HEADER}: {CHECKSUMS} is not a table of files")
    for name, digest in sums.items():
        if Path(name).name != name or name in ("", ".", ".."):
            raise ValueError(f"{HEADER} lists a file outside the folder: {name!r}")
        if not (path / name).is_file():
            raise RailwatchError(f"{path} is not a complete railwatch model: {name} is missing")
        if sha256_file(path / name) != digest:
            raise RailwatchError(
                f"{path} is not a readable railwatch model directory: {name} is damaged or was "
                f"replaced (its SHA-256 differs from the one saved in {HEADER}): train the "
                "model again or restore the folder from a copy")


def stale_siblings(path: Path, kind: str) -> list[Path]:
    """``.NAME.<kind>-PID`` folders beside ``path`` left by saves whose process is gone."""
    prefix = f".{path.name}.{kind}-"
    try:
        siblings = sorted(path.parent.iterdir())
    except OSError:
        return []
    found = []
    for p in siblings:
        pid = p.name[len(prefix):]
        if p.name.startswith(prefix) and pid.isdigit() and p.is_dir() and not p.is_symlink() \
                and int(pid) != os.getpid() and not _running(int(pid)):
            found.append(p)
    return found


def _running(pid: int) -> bool:
    """Whether process ``pid`` may still be running (when unsure: yes)."""
    if os.name != "posix":
        return True  # os.kill(pid, 0) would terminate it on Windows
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OSError, OverflowError):  # PermissionError: alive, another user's
        return True
    return True
