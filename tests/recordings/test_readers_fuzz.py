"""Fuzzing the recording readers: a broken or odd file never shows a traceback and never hangs.

The promise: for CSV (.csv), Parquet (.parquet), HDF5 (.h5) and MATLAB (.mat, v5 and v7.3)
files, opening a recording (``Recording(path, layout)``) and reading it (``chunks(rows)``, with
small ``rows`` too, and ``read()``) either succeeds, giving finite float32 channels, or raises
:class:`RailwatchError` whose message is one line and names the file. Never another exception,
never a hang (each test has a timeout), never a gigabyte allocation (resident memory is checked).
Inputs: random bytes (behind each format's magic too), truncations and bit flips of valid files,
and random content inside valid containers (odd headers, cells, types, shapes, names).
"""

from __future__ import annotations

import re
import resource
import tempfile
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, currently_in_test_context, event, given, settings
from hypothesis import strategies as st

from railwatch.errors import RailwatchError
from railwatch.recordings.layout import Layout
from railwatch.recordings.readers import Recording, write_recording
from support import write_mat73

FS = 100.0
LAYOUT = Layout(fs=FS, channels=("a", "b"), groups=("axle", "body"), time="t")
NAME = "rec-fuzz"  # file stem: distinctive, so "names the file" cannot pass by chance
EXTS = (".csv", ".parquet", ".h5", ".mat")
#: Column / dataset / variable names the random files use: the layout's and others.
NAMES = ("a", "b", "t", "v", "x", "A", "a ", "")
#: Resident memory the fuzzing may add (a header claiming gigabytes must not be believed).
MEMORY_LIMIT = 1 << 30

FUZZ = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                      HealthCheck.data_too_large])


def fuzz(examples: int) -> Callable[[Callable[..., None]], Callable[..., None]]:
    """Hypothesis settings and a timeout that turns a hang into a failure."""
    def wrap(test: Callable[..., None]) -> Callable[..., None]:
        return pytest.mark.timeout(120, method="thread")(
            settings(FUZZ, max_examples=examples)(test))
    return wrap


def max_rss() -> int:
    """This process's peak resident memory so far, in bytes."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # KiB on Linux


@contextmanager
def recording_file(ext: str) -> Iterator[Path]:
    with tempfile.TemporaryDirectory() as folder:
        yield Path(folder) / f"{NAME}{ext}"


def check_one_line_error(path: Path, layout: Layout, rows: int = 3) -> str | None:
    """Open and read ``path``: fine, or a one-line RailwatchError naming the file (returned)."""
    peak = max_rss()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # libraries may warn; only exceptions count here
            rec = Recording(path, layout)
            assert rec.n_samples >= 0
            blocks = list(rec.chunks(rows))
            assert all(0 < len(b) <= rows for b in blocks)
            whole = rec.read()
    except RailwatchError as e:
        message = str(e)
        assert "\n" not in message and "\r" not in message, repr(message)
        assert path.name in message, message
        outcome(message.replace(str(path), path.name).replace(path.name, "FILE"))
        return message
    finally:
        assert max_rss() - peak < MEMORY_LIMIT, "reading took over 1 GiB"
    assert whole.data.dtype == np.float32 and whole.data.shape[1] == len(layout.channels)
    assert np.isfinite(whole.data).all()
    outcome("read")
    return None


def outcome(message: str) -> None:
    """Tally outcomes (--hypothesis-show-statistics): reads, and errors by their first words."""
    if currently_in_test_context():
        words = re.sub(r"'[^']*'|\([^)]*\)?|(?<![A-Za-z])[-+.\d]+", "_", message).split()
        event(" ".join(words[:6])[:60])


# ----------------------------------------------------------------------------- valid files
def valid_columns(n: int = 40) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(1)
    return {"t": 5.0 + np.arange(n) / FS, "a": rng.normal(size=n), "b": rng.normal(size=n)}


#: Valid files to cut and damage: each format as write_recording writes it, and variants.
KINDS = (*EXTS, "mat-zip", "mat73", "h5-gzip", "parquet-plain")


def ext_of(kind: str) -> str:
    return {"mat-zip": ".mat", "mat73": ".mat", "h5-gzip": ".h5",
            "parquet-plain": ".parquet"}.get(kind, kind)


@cache
def valid_bytes(kind: str) -> bytes:
    """The bytes of a valid recording of ``kind`` (one of KINDS)."""
    cols = valid_columns()
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"v{ext_of(kind)}"
        if kind == "mat-zip":  # MATLAB v5, compressed
            import scipy.io

            scipy.io.savemat(path, {k: v.reshape(-1, 1) for k, v in cols.items()},
                             do_compression=True)
        elif kind == "mat73":
            write_mat73(path, cols)
        elif kind == "h5-gzip":
            import h5py

            with h5py.File(path, "w") as f:
                for k, v in cols.items():
                    f.create_dataset(k, data=v, chunks=(16,), compression="gzip", shuffle=True)
        elif kind == "parquet-plain":  # no compression, dictionary pages, several row groups
            import pyarrow as pa
            import pyarrow.parquet as pq

            pq.write_table(pa.table(cols), path, compression="none", row_group_size=15)
        else:
            write_recording(path, cols)
        assert check_one_line_error(path, LAYOUT) is None
        return path.read_bytes()


# ----------------------------------------------------------------------------- 1. random bytes
MAT_HEADER = b"MATLAB 5.0 MAT-file, fuzz".ljust(116) + b"\0" * 8 + b"\x00\x01IM"
MAGIC = {".csv": [b"a,b,t\n", b"a,b\n1,2\n"], ".parquet": [b"PAR1"],
         ".h5": [b"\x89HDF\r\n\x1a\n"], ".mat": [MAT_HEADER, MAT_HEADER + b"\x0e\0\0\0"]}


@st.composite
def random_file(draw: st.DrawFn) -> tuple[str, bytes]:
    ext = draw(st.sampled_from(EXTS))
    body = draw(st.binary(max_size=3000) | st.binary(max_size=4))
    if draw(st.booleans()):  # behind the format's magic, to get past the first check
        body = draw(st.sampled_from(MAGIC[ext])) + body
        if ext == ".parquet" and draw(st.booleans()):
            body += draw(st.binary(min_size=4, max_size=4)) + b"PAR1"
    return ext, body


@fuzz(500)
@given(random_file(), st.integers(1, 5))
def test_random_bytes(file: tuple[str, bytes], rows: int) -> None:
    ext, body = file
    with recording_file(ext) as path:
        path.write_bytes(body)
        check_one_line_error(path, LAYOUT, rows)


def test_empty_and_tiny_files_fail_in_one_line() -> None:
    for ext in EXTS:
        for body in (b"", b"\n", b"\0", b"a", b"a,b,t"):
            with recording_file(ext) as path:
                path.write_bytes(body)
                if ext == ".csv" and body == b"a,b,t":
                    with pytest.raises(RailwatchError, match="holds no data rows"):
                        Recording(path, LAYOUT).read()
                else:
                    assert check_one_line_error(path, LAYOUT) is not None


# ----------------------------------------------------------------------------- 2. truncations
@fuzz(400)
@given(st.sampled_from(KINDS), st.floats(0, 1), st.integers(1, 7))
def test_truncated_valid_files(kind: str, where: float, rows: int) -> None:
    good = valid_bytes(kind)
    with recording_file(ext_of(kind)) as path:
        path.write_bytes(good[:int(where * (len(good) - 1))])
        check_one_line_error(path, LAYOUT, rows)


# ----------------------------------------------------------------------------- 3. random content
@st.composite
def layouts(draw: st.DrawFn, names: tuple[str, ...] = ("a", "b", "x")) -> Layout:
    """One to three channels and maybe a time (and speed) column, present in the file or not."""
    channels = draw(st.lists(st.sampled_from(names), min_size=1, max_size=3, unique=True))
    rest = [n for n in ("t", "v", "missing") if n not in channels]
    time = draw(st.none() | st.sampled_from(rest))
    speed = draw(st.none() | st.sampled_from([n for n in rest if n != time]))
    return Layout(fs=FS, channels=tuple(channels), groups=("g",) * len(channels), time=time,
                  speed=speed)


def time_values(draw: st.DrawFn, n: int, clean: bool = False) -> np.ndarray:
    """A time column at 1 / FS: clean, or with random steps (gaps, repeats, reversals, jitter)."""
    odd = [0.0, -1 / FS, 2 / FS, 1.004 / FS, 1e-12, 1e300, 0.5 / FS]
    steps = draw(st.lists(st.sampled_from([1 / FS] * 6 + ([] if clean else odd)), min_size=n,
                          max_size=n))
    return draw(st.sampled_from([0.0, 3.5, -1.0, 1e15 if not clean else 1e5])) + np.cumsum(steps)


#: A third of the random files are clean (named columns numeric, time regular) so that reading
#: through to the end, across block boundaries, is fuzzed too, not only the first refusal.
CLEAN = st.integers(0, 2).map(lambda i: i == 0)


NUMBER = st.floats(-5, 5).map(lambda v: f"{v:.6g}")
CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**20, 10**20).map(str),
    st.sampled_from(["", " ", "nan", "NaN", "NA", "null", "inf", "-inf", "Infinity", "1e999",
                     "True", "false", "0x10", "1,5", '"1.5"', '"quoted, cell"', '"un', '""',
                     "1.5.2", "  2 ", "#", "\t", "é", "\\"]),
    st.text(max_size=6),
)


@st.composite
def csv_text(draw: st.DrawFn) -> tuple[bytes, Layout]:
    layout, clean = draw(layouts()), draw(CLEAN)
    header = draw(st.lists(st.sampled_from(NAMES) | st.text(max_size=4), min_size=0, max_size=6))
    if clean or draw(st.booleans()):
        header = list(dict.fromkeys(header + list(layout.columns)))
    draw(st.randoms()).shuffle(header)
    n = draw(st.integers(0, 25))
    times = time_values(draw, n, clean)
    lines = [",".join(header)]
    for i in range(n):
        width = len(header) + (0 if clean else draw(st.sampled_from([0] * 8 + [-1, 1, -9])))
        cells = draw(st.lists(NUMBER if clean else NUMBER | NUMBER | CELLS,
                              min_size=max(width, 0), max_size=max(width, 0)))
        for j, name in enumerate(header[:len(cells)]):
            if name == layout.time and (clean or draw(st.integers(0, 9))):
                cells[j] = f"{times[i]:.12g}"
        lines.append(",".join(cells))
    end = draw(st.sampled_from(["\n", "\r\n", "\r"]))
    text = end.join(lines) + draw(st.sampled_from([end, "", end * 2]))
    encoding = draw(st.sampled_from(["utf-8", "utf-8-sig", "latin-1", "utf-16"]))
    if clean:
        encoding = "utf-8"
    return text.encode(encoding, errors="replace"), layout


@fuzz(400)
@given(csv_text(), st.integers(1, 7))
def test_random_csv_content(content: tuple[bytes, Layout], rows: int) -> None:
    body, layout = content
    with recording_file(".csv") as path:
        path.write_bytes(body)
        check_one_line_error(path, layout, rows)


def arrow_column(draw: st.DrawFn, name: str, n: int, layout: Layout, clean: bool) -> Any:
    import pyarrow as pa

    if name == layout.time and (clean or draw(st.booleans())):
        return pa.array(time_values(draw, n, clean))
    numeric = ["float64", "float32", "int64", "int8"]
    kind = draw(st.sampled_from(numeric if clean and name in layout.columns else numeric + [
        "float16", "uint64", "bool", "string", "null", "nullable", "timestamp", "dictionary",
        "list", "struct", "decimal", "binary"]))
    values = draw(st.lists(st.floats(-1e6, 1e6), min_size=n, max_size=n))
    if kind in ("float64", "float32", "float16"):
        extreme = st.sampled_from([np.nan, np.inf, 0.0]) | st.floats(width=16)
        if not clean:
            values = [draw(extreme) if draw(st.integers(0, 15)) == 0 else v for v in values]
        with np.errstate(over="ignore"):  # 1e6 is infinite as float16: fine, one more case
            return pa.array(np.array(values, dtype=kind))
    if kind in ("int64", "int8", "uint64"):
        info = np.iinfo(kind)
        return pa.array(np.array(draw(st.lists(st.integers(int(info.min), int(info.max)),
                                               min_size=n, max_size=n)), dtype=kind))
    if kind == "nullable":  # integers with missing values
        return pa.array([None if draw(st.integers(0, 5)) == 0 else int(v) for v in values],
                        type=pa.int32())
    if kind == "bool":
        return pa.array([v > 0 for v in values])
    if kind == "string":
        return pa.array([draw(st.sampled_from([str(v), "x", "", "nan"])) for v in values])
    if kind == "null":
        return pa.nulls(n)
    if kind == "timestamp":
        return pa.array(np.arange(n).astype("datetime64[ms]"))
    if kind == "dictionary":
        return pa.array([str(int(v) % 3) for v in values]).dictionary_encode()
    if kind == "list":
        return pa.array([[v, v] for v in values])
    if kind == "struct":
        return pa.array([{"x": v} for v in values])
    if kind == "decimal":
        import decimal

        return pa.array([decimal.Decimal(int(v)) for v in values], type=pa.decimal128(12, 2))
    return pa.array([str(v).encode() for v in values], type=pa.binary())


@st.composite
def parquet_table(draw: st.DrawFn) -> tuple[Any, Layout, int | None]:
    import pyarrow as pa

    layout, clean = draw(layouts()), draw(CLEAN)
    names = draw(st.lists(st.sampled_from(NAMES + layout.columns), min_size=0, max_size=6))
    if clean or draw(st.booleans()):
        names = list(dict.fromkeys(names + list(layout.columns)))
    n = draw(st.integers(0, 30))
    arrays = [arrow_column(draw, name, n, layout, clean) for name in names]
    table = pa.Table.from_arrays(arrays, names=names) if names else pa.table({})
    return table, layout, draw(st.none() | st.integers(1, 9))


@fuzz(400)
@given(parquet_table(), st.integers(1, 7))
def test_random_parquet_content(content: tuple[Any, Layout, int | None], rows: int) -> None:
    import pyarrow.parquet as pq

    table, layout, row_group_size = content
    with recording_file(".parquet") as path:
        pq.write_table(table, path, row_group_size=row_group_size)
        check_one_line_error(path, layout, rows)


HDF5_NAMES = ("a", "b", "t", "v", "x", "g/a", "g/b", "a/b")


def hdf5_value(draw: st.DrawFn, n: int, clean: bool = False) -> Any:
    import h5py

    shape = draw(st.sampled_from([(n,), (n,), (n, 1), (1, n)] + ([] if clean else [
        (), (0,), (n, 2), (2, n, 1), (0, 1), (1, 1), "empty"])))
    if shape == "empty":
        return h5py.Empty(draw(st.sampled_from(["f8", "i4"])))
    size = int(np.prod(shape))
    kind = draw(st.sampled_from(["f8", "f4", "i8", "u1"] + ([] if clean else [
        "f2", "?", "c16", "S4", "vlen", "compound", "enum"])))
    finite = st.floats(-100, 100)
    base = np.array(draw(st.lists(finite if clean else finite | st.sampled_from([np.nan, np.inf]),
                                  min_size=size, max_size=size)), dtype="f8").reshape(shape)
    if kind in ("f8", "f4", "f2", "c16"):
        return base.astype(kind)
    if kind in ("i8", "u1", "?"):
        return np.nan_to_num(base, posinf=1, neginf=-1).astype(kind)
    if kind == "S4":
        return base.astype("S4")
    if kind == "vlen":
        return np.array([str(v) for v in base.reshape(-1)], dtype=h5py.string_dtype()).reshape(
            shape)
    if kind == "enum":
        return np.zeros(shape, dtype=h5py.enum_dtype({"A": 0, "B": 1}, basetype="u1"))
    out = np.zeros(shape, dtype=[("x", "f8"), ("y", "i4")])
    out["x"] = base
    return out


@st.composite
def hdf5_layout_and_data(draw: st.DrawFn) -> tuple[Layout, list[tuple[str, Any]], bool]:
    layout, clean = draw(layouts(("a", "b", "g/a"))), draw(CLEAN)
    names = draw(st.lists(st.sampled_from(HDF5_NAMES + layout.columns), max_size=6))
    if clean:  # the layout's first, so that nothing else takes their names
        names = list(layout.columns) + names
    elif draw(st.booleans()):
        names = names + list(layout.columns)
    n = draw(st.integers(0, 30))
    items = []
    for name in names:
        if name == layout.time and (clean or draw(st.booleans())):
            items.append((name, time_values(draw, n, clean)))
        elif clean and name in layout.columns:
            items.append((name, hdf5_value(draw, n, clean=True)))
        else:
            items.append((name, hdf5_value(draw, draw(st.sampled_from([n, n, n + 1, 1])))))
    return layout, items, draw(st.booleans())


@fuzz(400)
@given(hdf5_layout_and_data(), st.integers(1, 7))
def test_random_hdf5_content(content: tuple[Layout, list[tuple[str, Any]], bool],
                             rows: int) -> None:
    import h5py

    layout, items, chunked = content
    with recording_file(".h5") as path:
        with h5py.File(path, "w") as f:
            for name, value in items:
                if name in f or any(p in f and not isinstance(f[p], h5py.Group)
                                    for p in _parents(name)):
                    continue  # taken, or under a dataset
                shape = getattr(value, "shape", None)
                if chunked and shape and 0 not in shape:
                    f.create_dataset(name, data=value, chunks=True, compression="gzip",
                                     maxshape=(None,) * len(shape))
                else:
                    f.create_dataset(name, data=value)
            if "g" not in f:
                f.create_group("g")  # a group where a dataset may be expected
        check_one_line_error(path, layout, rows)


def _parents(name: str) -> list[str]:
    parts = name.split("/")
    return ["/".join(parts[:i]) for i in range(1, len(parts))]


def mat_value(draw: st.DrawFn, n: int, clean: bool = False) -> Any:
    kind = draw(st.sampled_from(["column", "row", "int"] + ([] if clean else [
        "matrix", "scalar", "empty", "bool", "complex", "string", "cell", "struct", "sparse",
        "nan"])))
    values = np.array(draw(st.lists(st.floats(-100, 100), min_size=n, max_size=n)))
    if kind == "column":
        return values.reshape(-1, 1)
    if kind == "row":
        return values
    if kind == "matrix":
        return np.zeros((n, 2))
    if kind == "scalar":
        return 1.5
    if kind == "empty":
        return np.zeros((0, 0))
    if kind == "int":
        return values.astype(np.int16)
    if kind == "bool":
        return values > 0
    if kind == "complex":
        return values + 1j
    if kind == "string":
        return draw(st.sampled_from(["", "abc", "1.5"]))
    if kind == "cell":
        return np.array([values, "x"], dtype=object)
    if kind == "struct":
        return {"x": values}
    if kind == "sparse":
        import scipy.sparse

        return scipy.sparse.csc_matrix(values.reshape(-1, 1))
    values[::3] = np.nan
    return values


@st.composite
def mat_variables(draw: st.DrawFn) -> tuple[dict[str, Any], Layout, dict[str, Any]]:
    layout, clean = draw(layouts()), draw(CLEAN)
    names = draw(st.lists(st.sampled_from(("a", "b", "t", "v", "x", "y")), max_size=5))
    if clean or draw(st.booleans()):
        names = names + list(layout.columns)
    n = draw(st.integers(0, 30))
    variables = {}
    for name in names:
        if name == layout.time and (clean or draw(st.booleans())):
            variables[name] = time_values(draw, n, clean).reshape(-1, 1)
        elif clean and name in layout.columns:
            variables[name] = mat_value(draw, n, clean=True)
        else:
            variables[name] = mat_value(draw, draw(st.sampled_from([n, n, n + 1, 1])))
    options = {"format": draw(st.sampled_from(["5", "5", "4"])),
               "do_compression": draw(st.booleans()),
               "oned_as": draw(st.sampled_from(["column", "row"]))}
    return variables, layout, options


@fuzz(400)
@given(mat_variables(), st.integers(1, 7))
def test_random_mat_content(content: tuple[dict[str, Any], Layout, dict[str, Any]],
                            rows: int) -> None:
    import scipy.io

    variables, layout, options = content
    with recording_file(".mat") as path:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                scipy.io.savemat(path, variables, **options)
        except (ValueError, TypeError, NotImplementedError):
            return  # scipy cannot write this (e.g. a cell or struct as MATLAB v4)
        check_one_line_error(path, layout, rows)


# ----------------------------------------------------------------------------- 4. bit flips
@fuzz(1000)
@given(st.sampled_from(KINDS), st.data())
def test_bit_flips_in_valid_files(kind: str, data: st.DataObject) -> None:
    body = bytearray(valid_bytes(kind))
    where = st.integers(0, len(body) - 1)
    for i in data.draw(st.lists(where, min_size=1, max_size=4), "positions"):
        body[i] ^= data.draw(st.integers(1, 255), "xor")
    with recording_file(ext_of(kind)) as path:
        path.write_bytes(bytes(body))
        check_one_line_error(path, LAYOUT, data.draw(st.integers(1, 7), "rows"))


# ----------------------------------------------------------------------------- regressions
def test_the_data_type_codes_that_crashed_scipy() -> None:
    """A damaged data-type code in a MATLAB v5 variable made scipy segfault; now one line."""
    import struct

    good = bytearray(valid_bytes(".mat"))
    tag = 128 + 376 + 48  # variable 2 ('a', 40 doubles): 56 bytes of header, then its data tag
    assert struct.unpack("<II", good[tag:tag + 8]) == (9, 320)  # miDOUBLE, 320 bytes
    for code in (0, 8, 14, 19, 20, 27145, 65535):
        body = good[:tag] + struct.pack("<I", code) + good[tag + 4:]
        with recording_file(".mat") as path:
            path.write_bytes(body)
            message = check_one_line_error(path, LAYOUT)
            assert message is not None and f"unknown type {code}" in message, message
    cut = good[:tag] + struct.pack("<I", 8 << 16 | 27145) + good[tag + 4:]  # a bad small element
    with recording_file(".mat") as path:
        path.write_bytes(cut)
        assert check_one_line_error(path, LAYOUT) is not None


def test_a_header_claiming_more_than_the_file_holds_is_not_believed() -> None:
    import h5py

    with recording_file(".h5") as path:
        with h5py.File(path, "w") as f:  # a billion values declared, none written
            f.create_dataset("a", shape=(10**9,), chunks=(1000,), maxshape=(None,), dtype="f8")
        message = check_one_line_error(path, Layout(fs=FS, channels=("a",), groups=("g",)))
        assert message is not None and "claims 1,000,000,000 values" in message, message


def test_values_beyond_float32_are_refused() -> None:
    cols = valid_columns()
    cols["b"][7] = 1e300
    with recording_file(".parquet") as path:
        write_recording(path, cols)
        message = check_one_line_error(path, LAYOUT)
        assert message is not None and "column 'b' is out of range at row 8" in message, message
