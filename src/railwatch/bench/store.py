"""The result store: finished cells on disk, written atomically, checked before reuse, one run
at a time per folder."""

from __future__ import annotations

import json
import logging
import os
import platform
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from railwatch.atomic import atomic_path, remove_stale_temporaries, sha256_file
from railwatch.bench.cell import Cell, fingerprint
from railwatch.bench.presets import Preset

log = logging.getLogger(__name__)


class ResultStore:
    """Finished cells on disk: ``cells/<key>.json`` (record) and ``cells/<key>.npz`` (arrays).

    Both are written atomically, the arrays first; the record, written last, marks the cell done
    and holds the SHA-256 of the arrays file, so a cell whose files were damaged afterwards (or
    whose arrays belong to another run) is computed again instead of being reused. One run at a
    time writes into a folder: :meth:`lock` takes ``OUT/.lock`` (released by the system when the
    process dies, however it dies) and clears what killed runs left half-written.
    """

    def __init__(self, out: Path) -> None:
        self.out = out
        self.dir = out / "cells"
        self.cache = out / "cache"

    def lock(self) -> Any:
        """Hold the folder for this process (a context manager); one-line error if taken."""
        return _FolderLock(self.out, self._clean)

    def _clean(self) -> None:
        """Remove temporary files and folders of killed runs (safe: we hold the lock)."""
        removed = sum(remove_stale_temporaries(d) for d in (self.out, self.dir, self.cache)
                      if d.is_dir())
        models = self.cache / "models"
        if models.is_dir():
            for stale in models.glob(".*"):
                shutil.rmtree(stale, ignore_errors=True)
                removed += 1
        if removed:
            log.info("removed %d temporary file(s) left by an interrupted run", removed)

    def done(self, preset: Preset, cell: Cell) -> bool:
        """Whether ``cell`` is finished, for this preset, with intact files."""
        path, arrays = self.dir / f"{cell.key}.json", self.dir / f"{cell.key}.npz"
        if not path.exists():
            return False
        try:
            record = json.loads(path.read_text())
            if record.get("fingerprint") != fingerprint(preset, cell):
                return False
            if "arrays_sha256" not in record:
                log.info("computing %s again: written by an older railwatch", cell.key)
                return False
            if record["arrays_sha256"] != sha256_file(arrays):
                raise ValueError("its arrays file does not match its record")
            return True
        except (OSError, ValueError, AttributeError) as e:
            log.warning("computing %s again: its result files are damaged (%s)", cell.key,
                        " ".join(str(e).split())[:120])
            return False

    def write(self, cell: Cell, record: dict[str, Any], arrays: dict[str, Any]) -> None:
        self.dir.mkdir(parents=True, exist_ok=True)
        target = self.dir / f"{cell.key}.npz"
        with atomic_path(target) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
        self.write_record(cell, {**record, "arrays_sha256": sha256_file(target)})  # marks it done

    def write_record(self, cell: Cell, record: dict[str, Any]) -> None:
        """Write (or replace) a cell's record; a finished cell's arrays stay."""
        with atomic_path(self.dir / f"{cell.key}.json") as tmp:
            tmp.write_text(json.dumps(record, indent=1, default=_json_default))

    def record(self, cell: Cell) -> dict[str, Any]:
        return dict(json.loads((self.dir / f"{cell.key}.json").read_text()))

    def arrays(self, cell: Cell) -> dict[str, Any]:
        with np.load(self.dir / f"{cell.key}.npz", allow_pickle=False) as f:
            return {k: f[k] for k in f.files}


class _FolderLock:
    """An exclusive ``flock`` on ``folder/.lock`` for the life of a ``with`` block; re-entrant
    in one process (the CLI holds it around a run and its report, ``run_grid`` inside)."""

    _held: ClassVar[dict[Path, int]] = {}

    def __init__(self, folder: Path, on_acquire: Callable[[], None]) -> None:
        self.path = (folder / ".lock").resolve()
        self.on_acquire = on_acquire
        self.fh: Any = None

    def __enter__(self) -> _FolderLock:
        import fcntl

        if self.path in self._held:
            self._held[self.path] += 1
            return self
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.fh = open(self.path, "a+")
        try:
            fcntl.flock(self.fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self.fh.seek(0)
            holder = self.fh.read().strip() or "another process"
            self.fh.close()
            from railwatch.errors import RailwatchError

            raise RailwatchError(f"{self.path.parent} is in use by another railwatch run "
                                 f"({holder}): wait for it to finish or give another --out") \
                from None
        self.fh.seek(0)
        self.fh.truncate()
        self.fh.write(f"pid {os.getpid()} on {platform.node()}\n")
        self.fh.flush()
        self._held[self.path] = 1
        try:
            self.on_acquire()
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        import fcntl

        self._held[self.path] -= 1
        if self._held[self.path] == 0 and self.fh is not None:
            del self._held[self.path]
            fcntl.flock(self.fh, fcntl.LOCK_UN)
            self.fh.close()


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, tuple | set):
        return list(value)
    raise TypeError(f"cannot store {type(value).__name__} in results")


def nan_to_none(value: Any) -> Any:
    if isinstance(value, float) and value != value:
        return None
    return value
