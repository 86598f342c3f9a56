"""Atomic file output: a result file is either complete or absent, never half-written; and
the checksum that tells a damaged file from the one written.

The file is written under a temporary name beside its destination (``.<stem>.<random><suffix>``),
flushed to disk (``fsync``) and renamed into place, and the folder's entry is flushed too: a
process killed at any point leaves the old file or the new one, and so does a power cut on a
vehicle computer, as far as the file system keeps its promises about ``fsync`` and ``rename``.
A killed writer can leave its temporary file behind; :func:`remove_stale_temporaries` clears
those where only one writer works on a folder (the benchmark's result store, under its lock).
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any


def sha256_file(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file's bytes, read in blocks (model folders and result stores record it
    to tell a damaged or replaced file from the one they wrote)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def fsync_path(path: str | os.PathLike[str]) -> None:
    """Flush a file's or a folder's content to disk (a no-op where folders cannot be opened)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:  # some file systems refuse fsync on folders
        pass
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it into place, else delete it.

    >>> import tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "a.txt"
    >>> with atomic_path(out) as tmp:
    ...     _ = tmp.write_text("done")
    >>> out.read_text()
    'done'
    """
    path = Path(path)
    fd, name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the file normal permissions
        fsync_path(tmp)
        os.replace(tmp, path)
        fsync_path(path.parent)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


#: The names :func:`atomic_path` gives its temporary files: ``.<stem>.<8 of mkstemp's>.<suffix>``.
_TEMPORARY = re.compile(r"^\..+\.[a-z0-9_]{8}(\.[A-Za-z0-9]+)?$")


def atomic_savez(path: str | os.PathLike[str], arrays: dict[str, Any]) -> Path:
    """``np.savez`` written atomically: complete at ``path``, or not there at all."""
    import numpy as np

    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    return Path(path)


def atomic_csv(path: str | os.PathLike[str], fields: Sequence[str],
               rows: Iterable[Mapping[str, Any]]) -> Path:
    """A CSV table (a header of ``fields``, then ``rows``) written atomically."""
    import csv

    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(fields), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    return Path(path)


def remove_stale_temporaries(folder: str | os.PathLike[str]) -> int:
    """Delete the temporary files :func:`atomic_path` left in ``folder`` (killed writers).

    Only for a folder that no other process is writing into at the same time. Returns the count.

    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> for name in (".results.k2j_9xq1.json", ".gitignore", "results.json"):
    ...     _ = (d / name).write_text("")
    >>> remove_stale_temporaries(d), sorted(p.name for p in d.iterdir())
    (1, ['.gitignore', 'results.json'])
    """
    count = 0
    for p in Path(folder).glob(".*"):
        if p.is_file() and _TEMPORARY.match(p.name):
            p.unlink(missing_ok=True)
            count += 1
    return count
