"""Readers for recordings as users have them: CSV, Parquet, HDF5 and MATLAB ``.mat``.

Every reader streams: :meth:`Recording.chunks` yields blocks of rows, so an hours-long recording
never has to fit in memory (MATLAB v5 files, which scipy reads whole, are the one exception;
v7.3 files are HDF5 and stream). Every block is checked on the way: each named column present,
numeric and finite; the time column (when named) increasing, at the layout's rate, without gaps.
Problems are one-line :class:`RailwatchError` messages naming the column and the row (1-based,
data rows only).

Every failure leaving a :class:`Recording` (opening, counting, reading) is one such line naming
the file: a damaged file, whatever the library reading it raises, becomes "cannot read FILE as
FORMAT: reason" (``tests/recordings/test_readers_fuzz.py`` fuzzes this promise).
"""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.errors import RailwatchError, naming, one_line
from railwatch.recordings.layout import Layout

FORMATS = {".csv": "csv", ".txt": "csv", ".parquet": "parquet", ".pq": "parquet", ".h5": "hdf5",
           ".hdf5": "hdf5", ".hdf": "hdf5", ".mat": "mat"}
#: How messages name each format ("cannot read x.mat as a MATLAB file").
FORMAT_NAMES = {"csv": "CSV", "parquet": "Parquet", "hdf5": "HDF5", "mat": "a MATLAB file"}
#: Rows per block when streaming (60 s at 2000 Hz).
CHUNK_ROWS = 120_000
#: A time step longer than this many sample periods is a gap.
GAP_FACTOR = 1.5
#: Allowed relative difference between the time column's median step and 1 / fs.
RATE_TOLERANCE = 0.01


@dataclass
class Chunk:
    """Consecutive rows of a recording: channels (n, C) float32 and the optional columns."""

    start: int  # index of the first row in the recording
    data: NDArray[np.float32]
    time: NDArray[np.float64] | None = None
    speed: NDArray[np.float64] | None = None
    position: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return len(self.data)


class Recording:
    """One recording file read through its layout. ``chunks()`` streams it; ``read()`` loads it."""

    def __init__(self, path: str | os.PathLike[str], layout: Layout) -> None:
        self.path = Path(path)
        self.layout = layout
        if not self.path.is_file():
            raise RailwatchError(f"no such recording: {self.path}")
        kind = FORMATS.get(self.path.suffix.lower())
        if kind is None:
            raise RailwatchError(
                f"cannot read {self.path.name}: unknown format {self.path.suffix or '(none)'}; "
                f"railwatch reads {', '.join(sorted(set(FORMATS)))}")
        self.format = kind
        with self._reading():
            self._source = _SOURCES[kind](self.path, layout)
            self.n_samples: int = self._source.n_rows()

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.layout.fs

    def chunks(self, rows: int = CHUNK_ROWS) -> Iterator[Chunk]:
        """Blocks of at most ``rows`` rows, checked, in order."""
        checker = _TimeChecker(self.layout)
        start = 0
        with self._reading():
            for columns in self._source.blocks(rows):
                chunk = _make_chunk(columns, self.layout, start)
                if not len(chunk):  # e.g. a CSV file with a header only
                    continue
                checker.check(chunk)
                start += len(chunk)
                yield chunk
            checker.finish()

    @contextmanager
    def _reading(self) -> Iterator[None]:
        """The boundary: any failure inside becomes one line that names the file."""
        try:
            yield
        except RailwatchError as e:
            raise naming(self.path.name, e) from None
        except Exception as e:  # noqa: BLE001 - a library choking on a damaged or odd file
            raise RailwatchError(f"cannot read {self.path.name} as "
                                 f"{FORMAT_NAMES[self.format]}: {_reason(e)}") from e

    def read(self) -> Chunk:
        """The whole recording as one chunk."""
        parts = list(self.chunks())
        if not parts:
            raise RailwatchError(f"{self.path} holds no data rows")

        def cat(name: str) -> Any:
            values = [getattr(p, name) for p in parts]
            return None if values[0] is None else np.concatenate(values)

        return Chunk(0, cat("data"), cat("time"), cat("speed"), cat("position"))


# ----------------------------------------------------------------------------- checks
def _make_chunk(columns: dict[str, NDArray[Any]], layout: Layout, start: int) -> Chunk:
    for name, values in columns.items():
        bad = ~np.isfinite(values)
        if bad.any():
            row = start + int(np.argmax(bad)) + 1
            what = "NaN or empty" if np.isnan(values[bad][0]) else "infinite"
            raise RailwatchError(f"column {name!r} is {what} at row {row} ({int(bad.sum())} such "
                                 "values in this block): clean or cut the recording there")
    for name in layout.channels:  # finite as float64 but infinite as float32: say so
        big = np.abs(columns[name]) > np.finfo(np.float32).max
        if big.any():
            i = int(np.argmax(big))
            raise RailwatchError(f"column {name!r} is out of range at row {start + i + 1} "
                                 f"({columns[name][i]:.6g}; channels are float32, at most "
                                 f"{np.finfo(np.float32).max:.3g})")
    data = np.stack([columns[c] for c in layout.channels], axis=1).astype(np.float32)

    def opt(name: str | None) -> NDArray[np.float64] | None:
        return None if name is None else columns[name].astype(np.float64)

    return Chunk(start, data, opt(layout.time), opt(layout.speed), opt(layout.position))


class _TimeChecker:
    """Increasing time at the layout's rate, no gaps, across block boundaries."""

    #: Steps collected before the rate is checked (a short last block says little).
    RATE_STEPS = 100

    def __init__(self, layout: Layout) -> None:
        self.layout = layout
        self.last: float | None = None
        self.steps: list[float] = []  # the first RATE_STEPS steps, for the rate check
        self.rate_checked = False

    def check(self, chunk: Chunk) -> None:
        if chunk.time is None or len(chunk) == 0:
            return
        t = chunk.time if self.last is None else np.concatenate([[self.last], chunk.time])
        first_row = chunk.start + (1 if self.last is None else 0)  # row of t[1], 1-based
        self.last = float(chunk.time[-1])
        if len(t) < 2:
            return
        dt = np.diff(t)
        period = 1.0 / self.layout.fs
        back = dt <= 0
        if back.any():
            i = int(np.argmax(back))
            raise RailwatchError(f"time column {self.layout.time!r} does not increase at row "
                                 f"{first_row + i + 1} (t = {t[i + 1]:.6g} s after {t[i]:.6g} s)")
        if not self.rate_checked:
            self.steps += dt[:self.RATE_STEPS - len(self.steps)].tolist()
            if len(self.steps) >= self.RATE_STEPS:
                self.finish()
        gaps = dt > GAP_FACTOR * period
        if gaps.any():
            i = int(np.argmax(gaps))
            raise RailwatchError(
                f"gap in time column {self.layout.time!r}: {dt[i] - period:.6g} s missing after "
                f"t = {t[i]:.6g} s (row {first_row + i}); split the recording at gaps")


    def finish(self) -> None:
        """Check the rate: the median of the first steps against 1 / fs."""
        if self.rate_checked or not self.steps:
            return
        self.rate_checked = True
        step = float(np.median(self.steps))
        if abs(step * self.layout.fs - 1.0) > RATE_TOLERANCE:
            raise RailwatchError(
                f"time column {self.layout.time!r} steps by {step:.6g} s ({1 / step:.6g} Hz) but "
                f"the layout says fs = {self.layout.fs:g} Hz: fix fs in the layout")


def _numeric(name: str, values: Any, start: int) -> NDArray[np.float64]:
    """A column as float64, or an error naming the first value that is not a number."""
    arr = np.asarray(values)
    if arr.dtype.kind in "fiub":
        return arr.astype(np.float64)
    import pandas as pd

    converted = pd.to_numeric(pd.Series(arr), errors="coerce").to_numpy(dtype=np.float64)
    bad = np.isnan(converted) & pd.Series(arr).notna().to_numpy()
    if bad.any():
        i = int(np.argmax(bad))
        raise RailwatchError(f"column {name!r} is not numeric: {str(arr[i])[:30]!r} at row "
                             f"{start + i + 1}")
    return converted


def _reason(e: BaseException) -> str:
    """A library's exception as a short line."""
    return one_line(e)[:160]


def _shown(name: str) -> str:
    """A name found in a file, as a message shows it: odd ones (blank, control) quoted."""
    return name if name.isprintable() and name.strip() == name and len(name) <= 60 else (
        repr(name[:60]))


def _missing(path: Path, wanted: tuple[str, ...], present: list[str], what: str) -> None:
    missing = [c for c in wanted if c not in present]
    if missing:
        shown = ", ".join(map(_shown, present[:12])) + (", ..." if len(present) > 12 else "")
        raise RailwatchError(f"{path.name} has no {what} {', '.join(map(repr, missing))} named in "
                             f"the layout; it has: {shown or 'nothing'}")


# ----------------------------------------------------------------------------- sources
class _Source:
    def __init__(self, path: Path, layout: Layout) -> None:
        self.path, self.layout = path, layout

    def n_rows(self) -> int:
        raise NotImplementedError

    def blocks(self, rows: int) -> Iterator[dict[str, NDArray[Any]]]:
        raise NotImplementedError


class _CSV(_Source):
    def __init__(self, path: Path, layout: Layout) -> None:
        super().__init__(path, layout)
        import pandas as pd

        try:
            header = list(pd.read_csv(path, nrows=0).columns)
        except (ValueError, OSError, pd.errors.ParserError) as e:  # UnicodeDecodeError included
            raise RailwatchError(f"cannot read {path} as CSV: {_reason(e)}") from None
        _missing(path, layout.columns, [str(c) for c in header], "column")

    def n_rows(self) -> int:
        with open(self.path, "rb") as fh:
            lines = sum(block.count(b"\n") for block in iter(lambda: fh.read(1 << 24), b""))
            fh.seek(-1, os.SEEK_END)
            unterminated = fh.read(1) != b"\n"
        return max(lines + unterminated - 1, 0)  # minus the header

    def blocks(self, rows: int) -> Iterator[dict[str, NDArray[Any]]]:
        import pandas as pd

        start = 0
        try:
            reader = pd.read_csv(self.path, usecols=list(self.layout.columns), chunksize=rows)
            for frame in reader:
                yield {c: _numeric(c, frame[c].to_numpy(), start) for c in self.layout.columns}
                start += len(frame)
        except (ValueError, pd.errors.ParserError) as e:
            raise RailwatchError(f"cannot read {self.path} as CSV near row {start + 1}: "
                                 f"{_reason(e)}") from None


class _Parquet(_Source):
    def __init__(self, path: Path, layout: Layout) -> None:
        super().__init__(path, layout)
        import pyarrow as pa
        import pyarrow.parquet as pq

        try:
            # Unbuffered, row group by row group: memory stays flat however long the file is
            # (pre-buffering held ~570 MB for a 60-minute six-channel run, ~230 MB without).
            self.file = pq.ParquetFile(path, pre_buffer=False, buffer_size=1 << 20)
        except (pa.ArrowException, OSError, ValueError) as e:  # ValueError: UnicodeDecodeError
            raise RailwatchError(f"cannot read {path} as Parquet: {_reason(e)}") from None
        try:
            try:  # a damaged footer may only show when its schema is decoded
                schema = self.file.schema_arrow
                names = list(schema.names)
            except (pa.ArrowException, ValueError) as e:
                raise RailwatchError(f"cannot read {path} as Parquet: {_reason(e)}") from None
            _missing(path, layout.columns, names, "column")
            for c in layout.columns:
                if names.count(c) > 1:
                    raise RailwatchError(f"{path.name} has {names.count(c)} columns named {c!r}")
                kind = schema.field(c).type
                if not (pa.types.is_integer(kind) or pa.types.is_floating(kind)):
                    raise RailwatchError(f"column {c!r} is not numeric: its Parquet type is "
                                         f"{kind}")
            if self.file.metadata.num_rows < 0:
                raise RailwatchError(f"cannot read {path} as Parquet: its footer claims "
                                     f"{self.file.metadata.num_rows} rows")
        except BaseException:
            self.file.close()
            raise

    def n_rows(self) -> int:
        return int(self.file.metadata.num_rows)

    def blocks(self, rows: int) -> Iterator[dict[str, NDArray[Any]]]:
        import pyarrow as pa

        start = 0
        try:
            for batch in self.file.iter_batches(batch_size=rows, columns=list(self.layout.columns),
                                                use_threads=False):
                yield {c: batch.column(c).to_numpy(zero_copy_only=False).astype(np.float64)
                       for c in self.layout.columns}
                start += batch.num_rows
        except (pa.ArrowException, OSError, ValueError) as e:  # a damaged page
            raise RailwatchError(f"cannot read {self.path} as Parquet near row {start + 1}: "
                                 f"{_reason(e)}") from None


class _HDF5(_Source):
    """Each layout name is a 1-D dataset path; MATLAB v7.3 files come here too."""

    def __init__(self, path: Path, layout: Layout) -> None:
        super().__init__(path, layout)
        import h5py

        try:
            self.file = h5py.File(path, "r")
        except (OSError, ValueError, RuntimeError) as e:
            raise RailwatchError(f"cannot read {path} as HDF5: {_reason(e)}") from None
        try:
            self._open_datasets()
        except BaseException:
            self.file.close()
            raise

    def _open_datasets(self) -> None:
        import h5py

        path, layout = self.path, self.layout
        present: list[str] = []
        try:  # a damaged object header or B-tree shows here, or where a dataset is opened
            self.file.visititems(lambda name, obj: present.append(
                name if isinstance(name, str) else name.decode("utf-8", "backslashreplace"))
                if isinstance(obj, h5py.Dataset) else None)
            _missing(path, tuple(c.strip("/") for c in layout.columns), present, "dataset")
            self.datasets = {c: self.file[c.strip("/")] for c in layout.columns}
            dtypes = {c: ds.dtype for c, ds in self.datasets.items()}
        except (RuntimeError, KeyError, ValueError, TypeError, OSError) as e:
            raise RailwatchError(f"cannot read {path} as HDF5: {_reason(e)}") from None
        lengths = set()
        for c, ds in self.datasets.items():
            if dtypes[c].kind not in "fiub":
                raise RailwatchError(f"dataset {c!r} is not numeric (dtype {dtypes[c]})")
            if ds.ndim not in (1, 2) or (ds.ndim == 2 and min(ds.shape) != 1):
                raise RailwatchError(f"dataset {c!r} has shape {ds.shape}: each name in the "
                                     "layout must be one 1-D column")
            lengths.add(int(np.prod(ds.shape)))
            self._check_stored(c, ds, dtypes[c].itemsize)
        if len(lengths) > 1:
            raise RailwatchError(f"the layout's datasets in {path.name} differ in length: "
                                 f"{sorted(lengths)}")
        self.length = lengths.pop() if lengths else 0

    def _check_stored(self, name: str, ds: Any, itemsize: int) -> None:
        """A (damaged) header claiming more values than the file holds is not believed.

        HDF5 reads values never written as the fill value, so such a claim would stream zeros
        for as long as it says. Uncompressed data kept in this file must fit in it.
        """
        plist = ds.id.get_create_plist()
        if ds.is_virtual or plist.get_external_count() or plist.get_nfilters():
            return
        claimed = int(np.prod(ds.shape)) * itemsize
        size = self.path.stat().st_size
        if claimed > size:
            raise RailwatchError(f"dataset {name!r} in {self.path.name} claims "
                                 f"{int(np.prod(ds.shape)):,} values ({claimed:,} bytes) but the "
                                 f"file has {size:,} bytes: it is damaged or was not fully "
                                 "written")

    def n_rows(self) -> int:
        return self.length

    def blocks(self, rows: int) -> Iterator[dict[str, NDArray[Any]]]:
        for start in range(0, self.length, rows):
            stop = min(start + rows, self.length)
            out = {}
            for c, ds in self.datasets.items():
                try:
                    if ds.ndim == 1:
                        block = ds[start:stop]
                    elif ds.shape[0] > 1:  # a column (n, 1)
                        block = ds[start:stop, 0]
                    else:  # a row (1, n): how MATLAB v7.3 stores a column vector
                        block = ds[0, start:stop]
                except (OSError, RuntimeError, ValueError) as e:  # a damaged chunk
                    raise RailwatchError(f"cannot read {self.path} as HDF5: dataset {c!r} near "
                                         f"row {start + 1}: {_reason(e)}") from None
                out[c] = np.asarray(block, dtype=np.float64)
            yield out


class _MAT(_Source):
    """MATLAB v4-v7.2 through scipy (read whole); v7.3 files are HDF5 and stream."""

    def __init__(self, path: Path, layout: Layout) -> None:
        super().__init__(path, layout)
        import scipy.io

        self.hdf5: _HDF5 | None = None
        try:
            _check_mat5(path, layout.columns)  # what would crash scipy, before it reads
            content = scipy.io.loadmat(path, variable_names=list(layout.columns))
        except NotImplementedError:  # v7.3: HDF5 inside
            content = None
        except (ValueError, OSError, TypeError, IndexError, OverflowError, MemoryError,
                zlib.error, scipy.io.matlab.MatReadError) as e:
            raise RailwatchError(f"cannot read {path} as a MATLAB file: {_reason(e)}") from None
        if content is None:
            self.hdf5 = _HDF5(path, layout)
            return
        _missing(path, layout.columns, [k for k in content if not k.startswith("__")],
                 "variable")
        self.columns: dict[str, NDArray[Any]] = {}
        for c in layout.columns:
            arr = np.asarray(content[c])
            if arr.dtype.kind not in "fiub":
                raise RailwatchError(f"variable {c!r} is not numeric (MATLAB class "
                                     f"{arr.dtype})")
            if sum(n > 1 for n in arr.shape) > 1:
                raise RailwatchError(f"variable {c!r} has shape {arr.shape}: each name in the "
                                     "layout must be one vector")
            self.columns[c] = arr.reshape(-1).astype(np.float64)
        lengths = {len(v) for v in self.columns.values()}
        if len(lengths) > 1:
            raise RailwatchError(f"the layout's variables in {path.name} differ in length: "
                                 f"{sorted(lengths)}")

    def n_rows(self) -> int:
        if self.hdf5 is not None:
            return self.hdf5.n_rows()
        return len(next(iter(self.columns.values())))

    def blocks(self, rows: int) -> Iterator[dict[str, NDArray[Any]]]:
        if self.hdf5 is not None:
            yield from self.hdf5.blocks(rows)
            return
        for start in range(0, self.n_rows(), rows):
            yield {c: v[start:start + rows] for c, v in self.columns.items()}


# ----------------------------------------------------------------------------- MATLAB v5 check
#: MATLAB v5 data types scipy can turn into an array (it indexes a table with the code unchecked).
_MI_ARRAY_TYPES = frozenset({1, 2, 3, 4, 5, 6, 7, 9, 12, 13, 16, 17, 18})
_MI_MATRIX, _MI_COMPRESSED = 14, 15
_MX_NUMERIC = range(6, 16)  # double, single, int8 ... uint64
_MX_NAMES = {1: "cell", 2: "struct", 3: "object", 4: "char", 5: "sparse", 16: "function",
             17: "opaque"}


class _Mat5Variable:
    """The bytes of one MATLAB v5 variable, read as scipy reads them (inflated if compressed)."""

    def __init__(self, fh: Any, start: int, size: int, compressed: bool, order: str) -> None:
        self.fh, self.left, self.order = fh, size, order
        self.inflate = zlib.decompressobj() if compressed else None
        fh.seek(start)

    def read(self, n: int) -> bytes:
        """``n`` bytes; EOFError if the data end first."""
        if self.inflate is None:
            out = bytes(self.fh.read(n))
        else:
            buf = bytearray()
            while len(buf) < n and not self.inflate.eof:
                data = self.inflate.unconsumed_tail
                if not data and self.left > 0:
                    data = self.fh.read(min(self.left, 1 << 16))
                    self.left = self.left - len(data) if data else 0
                more = self.inflate.decompress(data, n - len(buf))
                if not more and not data:
                    break
                buf += more
            out = bytes(buf)
        if len(out) < n:
            raise EOFError
        return out

    def skip(self, n: int) -> None:
        if self.inflate is None:
            self.fh.seek(n, os.SEEK_CUR)
            return
        while n > 0:
            step = min(n, 1 << 20)
            self.read(step)
            n -= step

    def tag(self) -> tuple[int, int, bytes | None]:
        """An element's data type and byte count, and its data if small (inside the tag)."""
        raw = self.read(8)
        mdtype, count = struct.unpack(self.order + "II", raw)
        if mdtype >> 16:  # small data element: type and count share the first word
            return mdtype & 0xFFFF, mdtype >> 16, raw[4:4 + (mdtype >> 16)]
        return mdtype, count, None

    def element(self, keep: int = 0) -> bytes | None:
        """Pass one element; its data if they are at most ``keep`` bytes."""
        _, count, small = self.tag()
        if small is not None:
            return small
        padded = count + (8 - count % 8) % 8
        if count > keep:
            self.skip(padded)
            return None
        body = self.read(padded)
        return body[:count]


def _check_mat5(path: Path, names: tuple[str, ...]) -> None:
    """Refuse what would crash scipy's MATLAB v5 reader in the variables railwatch reads.

    scipy (1.17 at least) indexes a C table with an element's data-type code unchecked: one
    damaged byte there is a segmentation fault, not an exception. This walks the file as scipy
    does (same framing, same variables: the first of each name) and checks those codes first.
    Other damage is left to scipy, which raises. Non-numeric variables are refused here.
    """
    with open(path, "rb") as fh:
        head = fh.read(128)
        if len(head) < 128 or 0 in head[:4]:
            return  # v4 (read in Python) or too short: scipy's own checks
        if head[124 + int(head[126] == ord("I"))] != 1:
            return  # v7.3 (HDF5) or unknown: not scipy's v5 reader
        order = "<" if head[126:128] == b"IM" else ">"
        size = os.fstat(fh.fileno()).st_size
        wanted, pos = set(names), 128
        while wanted and pos + 8 <= size:
            fh.seek(pos)
            mdtype, nbytes = struct.unpack(order + "II", fh.read(8))
            if nbytes == 0 or mdtype not in (_MI_MATRIX, _MI_COMPRESSED):
                return  # scipy refuses it
            var = _Mat5Variable(fh, pos + 8, nbytes, mdtype == _MI_COMPRESSED, order)
            pos += 8 + nbytes
            try:
                _check_mat5_variable(path, var, wanted)
            except (zlib.error, struct.error, EOFError):
                return  # damage scipy meets the same way, and raises on


def _check_mat5_variable(path: Path, var: _Mat5Variable, wanted: set[str]) -> None:
    if var.inflate is not None and var.tag()[0] != _MI_MATRIX:
        return
    var.read(8)  # the array flags' tag
    flags = struct.unpack(var.order + "I", var.read(8)[:4])[0]
    mclass, complex_ = flags & 0xFF, bool(flags >> 11 & 1)
    if mclass != 17:  # all but opaque objects have dimensions
        var.element()
    raw = var.element(keep=1 << 10)  # a longer name is none railwatch reads
    name = None if raw is None else raw.decode("latin1")
    if name not in wanted:
        return
    wanted.discard(name)
    if mclass not in _MX_NUMERIC:
        raise RailwatchError(f"variable {name!r} is not numeric (MATLAB class "
                             f"{_MX_NAMES.get(mclass, mclass)})")
    for part in range(2 if complex_ else 1):  # real, then imaginary values
        mdtype, count, small = var.tag()
        if mdtype not in _MI_ARRAY_TYPES:
            raise RailwatchError(f"cannot read {path} as a MATLAB file: variable {name!r} holds "
                                 f"values of unknown type {mdtype} (a damaged file)")
        if part == 0 and complex_ and small is None:
            var.skip(count + (8 - count % 8) % 8)


_SOURCES: dict[str, type[_Source]] = {"csv": _CSV, "parquet": _Parquet, "hdf5": _HDF5,
                                      "mat": _MAT}


# ----------------------------------------------------------------------------- writers
def write_recording(path: str | os.PathLike[str], columns: dict[str, NDArray[Any]]) -> Path:
    """Write equal-length 1-D columns in the format of ``path``'s extension (atomically).

    The inverse of the readers, used to write synthesised test recordings in every format.
    """
    from railwatch.atomic import atomic_path

    path = Path(path)
    kind = FORMATS.get(path.suffix.lower())
    if kind is None:
        raise RailwatchError(f"cannot write {path.name}: unknown format {path.suffix}; use one "
                             f"of {', '.join(sorted(set(FORMATS)))}")
    with atomic_path(path) as tmp:
        if kind == "csv":
            import pandas as pd

            pd.DataFrame(columns).to_csv(tmp, index=False, float_format="%.10g")
        elif kind == "parquet":
            import pyarrow as pa
            import pyarrow.parquet as pq

            pq.write_table(pa.table(columns), tmp)
        elif kind == "hdf5":
            import h5py

            with h5py.File(tmp, "w") as f:
                for name, values in columns.items():
                    f.create_dataset(name, data=values, chunks=True)
        else:
            import scipy.io

            scipy.io.savemat(tmp, {k: np.asarray(v).reshape(-1, 1) for k, v in columns.items()})
    return path


def recording_start(path: str | os.PathLike[str], layout: Layout) -> str | None:
    """When a recording began: its first sample's ``timestamp`` (the layout's column; None
    without one) as ISO 8601 to the second. A number is seconds since 1970-01-01 UTC; a
    date-time with a zone is converted to UTC (the result then ends in ``Z``), one without a
    zone is taken as it is."""
    if not layout.timestamp:
        return None
    path, column = Path(path), layout.timestamp
    value: Any = None
    try:
        if FORMATS.get(path.suffix.lower()) == "csv":
            import pandas as pd

            value = pd.read_csv(path, usecols=[column], nrows=1)[column].iloc[0]
        elif FORMATS.get(path.suffix.lower()) == "parquet":
            import pyarrow.parquet as pq

            with pq.ParquetFile(path) as f:
                table = f.read_row_group(0, columns=[column])
                value = table.column(0)[0].as_py() if table.num_rows else None
        else:  # HDF5 and MATLAB hold numbers: seconds since 1970
            rec = Recording(path, replace(layout, time=column, speed=None, position=None))
            first = next(rec.chunks(rows=1)).time
            value = float(first[0]) if first is not None else None
    except RailwatchError:
        raise
    except (KeyError, ValueError, OSError, IndexError, StopIteration) as e:
        raise RailwatchError(f"{path.name}: cannot read its timestamp column {column!r} "
                             f"({_reason(e)})") from None
    return iso_time(value, f"{path.name}: timestamp column {column!r}")


#: Seconds between the points of a recording's route (:func:`recording_route`): 10 Hz, as
#: often as common GNSS receivers fix.
ROUTE_EVERY_S = 0.1


def recording_route(path: str | os.PathLike[str], layout: Layout,
                    every_s: float = ROUTE_EVERY_S) -> NDArray[np.float64] | None:
    """Where a recording was on the earth (the layout's ``latitude`` and ``longitude``
    columns; None without them): ``(k, 3)`` time (s, counted as the scan's score profile
    counts it: the time column, else the sample's index / fs), latitude and longitude (degrees,
    WGS 84), every ``every_s`` and at the last sample; samples without a fix (NaN) left out."""
    if not (layout.latitude and layout.longitude):
        return None
    lay = Layout(fs=layout.fs, channels=(layout.latitude, layout.longitude),
                 groups=("gnss", "gnss"), time=layout.time)
    rec = Recording(path, lay)
    step = max(1, round(every_s * layout.fs))
    rows, start, last = [], 0, None
    with rec._reading():
        for block in rec._source.blocks(CHUNK_ROWS):
            lat, lon = block[lay.channels[0]], block[lay.channels[1]]
            n = len(lat)
            if not n:
                continue
            for name, values, bound in ((lay.channels[0], lat, 90), (lay.channels[1], lon, 180)):
                bad = np.abs(np.nan_to_num(values)) > bound
                if bad.any():
                    i = int(np.argmax(bad))
                    raise RailwatchError(
                        f"column {name!r} holds {values[i]:.6g} at row {start + i + 1}: GNSS "
                        f"fixes are degrees (WGS 84), within ±{bound}")
            time = block[lay.time] if lay.time else (start + np.arange(n)) / layout.fs
            idx = np.arange((-start) % step, n, step)
            rows.append(np.stack([time[idx], lat[idx], lon[idx]], axis=1))
            last = np.array([[time[-1], lat[-1], lon[-1]]])
            start += n
    if last is not None and (not rows or (start - 1) % step):
        rows.append(last)
    route = np.concatenate(rows) if rows else np.zeros((0, 3))
    return route[np.isfinite(route).all(axis=1)]


def iso_time(value: Any, what: str) -> str:
    """A date-time (or seconds since 1970-01-01 UTC) as ISO 8601 to the second (module's
    :func:`recording_start`)."""
    import datetime

    import pandas as pd

    try:
        if isinstance(value, int | float | np.integer | np.floating) and not isinstance(
                value, bool):
            if not np.isfinite(value):
                raise ValueError(value)
            stamp = pd.Timestamp(float(value), unit="s", tz="UTC")
        else:
            stamp = pd.Timestamp(value)
    except (ValueError, TypeError, OverflowError):
        raise RailwatchError(f"{what}: {value!r} is not a date-time (ISO 8601, e.g. "
                             "2026-03-01T08:15:00Z) nor seconds since 1970-01-01 UTC") from None
    if pd.isna(stamp):
        raise RailwatchError(f"{what}: the first sample has no time")
    if stamp.tzinfo is not None:
        utc = stamp.tz_convert(datetime.timezone.utc).tz_localize(None)
        return utc.isoformat(timespec="seconds") + "Z"
    return stamp.isoformat(timespec="seconds")
