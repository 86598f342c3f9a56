"""The benchmark under faults: killed mid-cell or mid-write, damaged cell files, two runs on one
folder. Promise: a rerun finishes, reuses every intact finished cell, and gives the results of an
uninterrupted run; no half-written cell file is ever read or reused.

Every run here is a real process (``python -m railwatch.cli``, or a small script that kills itself
with SIGKILL at a chosen point of writing), so nothing gets a chance to clean up after itself.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from railwatch.bench.store import ResultStore
from railwatch.cli import main

ARGS = ["bench", "--preset", "smoke", "--stages", "1,3", "--detectors", "matched-filter,cnn-ae"]
N_CELLS = 4
#: What a cell's result is; timings, the host and the arrays file's checksum (its zip entries
#: carry the time of writing) legitimately differ between two runs.
VARYING = {"fit_s", "score_s", "cell_s", "environment", "arrays_sha256"}

# Runs railwatch's CLI after arranging to SIGKILL itself at one point of writing results:
#   argv: POINT N CLI-ARGS...   POINT: arrays | record | report; N: at the N-th such write.
KILLER = r"""
import os, signal, sys
import numpy as np
from railwatch.atomic import atomic_path
from railwatch.bench import store
from railwatch.report import run_report as report

point, nth = sys.argv[1], int(sys.argv[2])
calls = [0]

def die():
    os.kill(os.getpid(), signal.SIGKILL)

if point == "arrays":  # half an .npz written into the cell's temporary file
    real_savez = np.savez
    def savez(fh, **arrays):
        if "/cells/" in str(getattr(fh, "name", "")):
            calls[0] += 1
            if calls[0] == nth:
                fh.write(b"PK\x03\x04" + bytes(200)); fh.flush(); die()
        return real_savez(fh, **arrays)
    np.savez = savez
elif point == "record":  # half a record written into its temporary file
    real_record = store.ResultStore.write_record
    def write_record(self, cell, record):
        calls[0] += 1
        if calls[0] == nth:
            with atomic_path(self.dir / f"{cell.key}.json") as tmp:
                tmp.write_text('{"stage": 1, "detec'); die()
        return real_record(self, cell, record)
    store.ResultStore.write_record = write_record
elif point == "report":  # half of results.json written
    real_text = report.write_text
    def write_text(path, text):
        if path.name == "results.json":
            with atomic_path(path) as tmp:
                tmp.write_text(text[: len(text) // 2]); die()
        return real_text(path, text)
    report.write_text = write_text
from railwatch.cli import main
sys.exit(main(sys.argv[3:]))
"""


def railwatch(*args: str, script: list[str] | None = None) -> subprocess.Popen[bytes]:
    """A railwatch process (or the killer script with ``script`` arguments first)."""
    cmd = [sys.executable, "-c", KILLER, *script, *args] if script else \
        [sys.executable, "-m", "railwatch.cli", *args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def finish(proc: subprocess.Popen[bytes], timeout: float = 300) -> tuple[int, str]:
    _, err = proc.communicate(timeout=timeout)
    return proc.returncode, err.decode()


def results(out: Path) -> dict[str, dict]:  # type: ignore[type-arg]
    """Each cell's result (without what varies between runs) and its arrays."""
    found = {}
    store = ResultStore(out)
    for c in json.loads((out / "results.json").read_text())["cells"]:
        key = f"stage{c['stage']}-{c['detector']}-seed{c['seed']}"
        with np.load(store.dir / f"{key}.npz") as f:
            arrays = {k: f[k].tolist() for k in f.files}
        found[key] = {**{k: v for k, v in c.items() if k not in VARYING}, "arrays": arrays}
    return found


def assert_no_damaged_cell_files(out: Path) -> None:
    """Every cell file under its final name is complete (temporary ones may be left)."""
    for p in (out / "cells").glob("[!.]*.json"):
        json.loads(p.read_text())
    for p in (out / "cells").glob("[!.]*.npz"):
        with np.load(p) as f:
            [f[k] for k in f.files]


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict[str, dict]:  # type: ignore[type-arg]
    """An uninterrupted run, in its own process like the interrupted ones."""
    out = tmp_path_factory.mktemp("reference") / "run"
    code, err = finish(railwatch("-q", *ARGS, "--out", str(out)))
    assert code == 0, err
    return results(out)


@pytest.mark.slow
def test_killed_mid_cell_resumes_to_the_same_results(reference, tmp_path) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "run"
    proc = railwatch("-q", *ARGS, "--out", str(out))
    deadline = time.monotonic() + 240
    while not list((out / "cells").glob("[!.]*.json")) and proc.poll() is None:
        assert time.monotonic() < deadline, "the run never finished a cell"
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)  # the next cell is being trained or scored
    proc.wait()
    finished = {p: p.stat().st_mtime_ns for p in (out / "cells").glob("[!.]*")}
    assert 2 <= len(finished) < 2 * N_CELLS, "killed too late to test anything"
    assert_no_damaged_cell_files(out)

    code, err = finish(railwatch(*ARGS, "--out", str(out)))
    assert code == 0, err
    assert f"({len(finished) // 2} reused from an earlier run)" in err
    assert "bench: 4/4 cells (100%)" in err  # progress lines without a terminal
    assert {p: p.stat().st_mtime_ns for p in finished} == finished  # reused, not rewritten
    assert results(out) == reference


@pytest.mark.slow
@pytest.mark.parametrize(("point", "nth"), [("arrays", 2), ("record", 3), ("report", 1)])
def test_killed_while_writing_results(point: str, nth: int, reference, tmp_path) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "run"
    code, _ = finish(railwatch("-q", *ARGS, "--out", str(out), script=[point, str(nth)]))
    assert code == -signal.SIGKILL
    left = [p for d in (out, out / "cells") for p in d.glob(".*") if p.name != ".lock"]
    assert left, "the kill should have left a temporary file"
    assert_no_damaged_cell_files(out)
    if point == "report":
        assert not (out / "results.json").exists()  # no half-written results either
    done_before = len(list((out / "cells").glob("[!.]*.json")))
    assert done_before == {"arrays": 1, "record": 2, "report": N_CELLS}[point]

    code, err = finish(railwatch(*ARGS, "--out", str(out)))
    assert code == 0, err
    assert f"({done_before} reused from an earlier run)" in err
    assert not any(p.exists() for p in left)  # what the killed run left is cleared
    assert results(out) == reference


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["truncate-arrays", "delete-arrays", "swap-arrays",
                                    "garble-record"])
def test_damaged_cell_is_computed_again(damage: str, tmp_path, capsys, caplog) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "run"
    assert main(["-q", *ARGS, "--out", str(out)]) == 0
    before = results(out)
    cells = out / "cells"
    victim, other = cells / "stage1-cnn-ae-seed0", cells / "stage3-cnn-ae-seed0"
    if damage == "truncate-arrays":
        data = victim.with_suffix(".npz").read_bytes()
        victim.with_suffix(".npz").write_bytes(data[: len(data) // 2])
    elif damage == "delete-arrays":
        victim.with_suffix(".npz").unlink()
    elif damage == "swap-arrays":  # a complete, readable file that belongs to another cell
        victim.with_suffix(".npz").write_bytes(other.with_suffix(".npz").read_bytes())
    else:
        victim.with_suffix(".json").write_text('{"fingerprint": ')
    capsys.readouterr()
    assert main([*ARGS, "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"({N_CELLS - 1} reused from an earlier run)" in err
    if damage != "garble-record":
        assert "computing stage1-cnn-ae-seed0 again: its result files are damaged" in caplog.text
    assert results(out) == before


def test_one_run_at_a_time_per_folder(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "run"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from pathlib import Path; "
         "from railwatch.bench.store import ResultStore\n"
         "with ResultStore(Path(sys.argv[1])).lock():\n print('held', flush=True); "
         "time.sleep(600)", str(out)], stdout=subprocess.PIPE)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == b"held\n"
        assert main([*ARGS, "--out", str(out)]) == 1
        err = capsys.readouterr().err
        assert "is in use by another railwatch run (pid" in err and err.count("\n") == 1, err
    finally:
        holder.kill()  # SIGKILL: the system releases the lock
        holder.wait()
    with ResultStore(out).lock():
        assert (out / ".lock").read_text().startswith(f"pid {os.getpid()}")
