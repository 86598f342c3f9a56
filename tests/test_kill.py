"""``train`` and ``detect`` killed with SIGKILL (power cut, OOM killer, ``kill -9``) mid-run.

Real processes (``python -m railwatch.cli``) are killed once they are in the middle of work (a
progress or status line on stderr says so). Afterwards there is no events file, and the model
folder is absent or still the previous complete model; the same command run again succeeds.
A small wrapper script kills ``train`` from inside :meth:`Detector.save` (half-way through
writing the weights or the statistics, before the swap, between the two renames of the swap):
the old model (or nothing) is left and loads, the next save works and clears the leftovers.

Every wait polls with a generous limit (:data:`LIMIT_S`): the machine may be loaded.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from railwatch.cli import main
from railwatch.detection.pipeline import read_events
from railwatch.detectors import create, load_detector
from railwatch.errors import RailwatchError
from railwatch.windows import load_windows
from support import TINY, tiny_config

LIMIT_S = 60.0  # longest wait for anything a subprocess should do
RAILWATCH = [sys.executable, "-m", "railwatch.cli"]
pytestmark = pytest.mark.skipif(os.name != "posix", reason="SIGKILL and /proc are POSIX")


class Running:
    """A subprocess whose stderr lines are collected by a thread, so polling never blocks."""

    def __init__(self, args: list[str]) -> None:
        # One thread: the child works longer and leaves a core to the polling test.
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}
        self.proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                     text=True, env=env)
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line.rstrip("\n"))

    def wait_for_line(self, pattern: str) -> str:
        """The first stderr line matching ``pattern``, while the process still runs."""
        deadline = time.monotonic() + LIMIT_S
        while time.monotonic() < deadline:
            for line in list(self.lines):
                if re.search(pattern, line):
                    return line
            if self.proc.poll() is not None:
                break
            time.sleep(0.02)
        self.proc.kill()
        self.proc.wait()
        pytest.fail(f"no line matching {pattern!r} while running (exit {self.proc.returncode}):"
                    f"\n" + "\n".join(self.lines))

    def kill(self) -> None:
        """SIGKILL; the process must still have been working (else the test proves nothing)."""
        assert self.proc.poll() is None, "finished before it could be killed: make the work " \
                                         "longer\n" + "\n".join(self.lines)
        os.kill(self.proc.pid, signal.SIGKILL)
        self.wait_killed()

    def finish(self) -> None:
        """Wait for a normal end, exit code 0."""
        self.proc.wait(timeout=4 * LIMIT_S)
        self._reader.join(timeout=LIMIT_S)
        assert self.proc.returncode == 0, "\n".join(self.lines)

    def wait_killed(self) -> None:
        self.proc.wait(timeout=LIMIT_S)
        self._reader.join(timeout=LIMIT_S)
        assert self.proc.returncode == -signal.SIGKILL, (self.proc.returncode, self.lines)


def leftovers(folder: Path, name: str) -> list[str]:
    """Hidden siblings a save of ``folder/name`` may leave: ``.name.tmp-PID``, ``.name.old-PID``."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(f".{name}."))


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 30-s recording (training) and 40 windows of stage 5 (``train --data``)."""
    d = tmp_path_factory.mktemp("kill")
    assert main(["-q", "generate-run", "--minutes", "0.5", "--seed", "1",
                 "--out", str(d / "run.parquet")]) == 0
    assert main(["-q", "generate", "--stage", "5", "--n", "40", "--seed", "0",
                 "--out", str(d / "windows.npz")]) == 0
    return d


# ----------------------------------------------------------------------------- train
@pytest.mark.slow
def test_train_killed_mid_fit_leaves_nothing_or_the_old_model(work: Path, tmp_path: Path) -> None:
    out = tmp_path / "model"
    # Long enough to be killed in the middle (~4 s of epochs on an idle machine; never stops
    # early), the recording and the settings of the short run below otherwise.
    base = ["train", "--detector", "cnn-ae", "--recordings", str(work / "run.parquet"),
            "--layout", str(work / "run.layout.toml"), "--config", str(TINY / "cnn-ae.yaml"),
            "--out", str(out)]
    command = [*base, "--set", "seed=1", "--set", "epochs=300", "--set", "patience=0"]

    # 1. No model before: none after.
    run = Running([*RAILWATCH, *command])
    run.wait_for_line(r"training cnn-ae")
    run.kill()
    assert not out.exists() and leftovers(tmp_path, "model") == []
    with pytest.raises(RailwatchError, match="no model directory"):
        load_detector(out)

    # 2. A previous model: it stays, complete, and is still the previous one (seed 0).
    assert main(["-q", *base, "--set", "seed=0", "--set", "epochs=1"]) == 0
    before = (out / "weights.pt").read_bytes()
    run = Running([*RAILWATCH, *command])
    run.wait_for_line(r"training cnn-ae")
    run.kill()
    old = load_detector(out)
    assert old.config.seed == 0 and (out / "weights.pt").read_bytes() == before  # type: ignore[attr-defined]
    assert leftovers(tmp_path, "model") == []

    # 3. The same command again succeeds and replaces it.
    Running([*RAILWATCH, *command]).finish()
    assert load_detector(out).config.seed == 1  # type: ignore[attr-defined]
    assert leftovers(tmp_path, "model") == []


# ----------------------------------------------------------------------------- detect
@pytest.mark.slow
def test_detect_killed_mid_scan_writes_no_events(work: Path, tmp_path: Path) -> None:
    model, recording = tmp_path / "model", tmp_path / "long.parquet"
    assert main(["-q", "train", "--detector", "aft-attention", "--recordings",
                 str(work / "run.parquet"), "--layout", str(work / "run.layout.toml"),
                 "--config", str(TINY / "aft-attention.yaml"), "--out", str(model)]) == 0
    # An hour at 100 Hz: three blocks of 20 min; the first progress line comes after the first,
    # two thirds of the work to go (~2 s on one idle core).
    assert main(["-q", "generate-run", "--minutes", "60", "--fs", "100", "--seed", "2",
                 "--out", str(recording)]) == 0
    events = tmp_path / "events.csv"
    command = ["detect", "--model", str(model), "--recording", str(recording),
               "--layout", str(tmp_path / "long.layout.toml"), "--out", str(events)]
    run = Running([*RAILWATCH, *command])
    run.wait_for_line(r"^detect: ")
    run.kill()
    assert not events.exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".events")] == []
    Running([*RAILWATCH, *command]).finish()
    assert len(read_events(events)) > 0


# ----------------------------------------------------------------------------- inside save
#: Run as ``python -c KILLER WHERE railwatch-arguments...``: the CLI, with the save step named
#: WHERE made to SIGKILL its own process.
KILLER = r"""
import io, os, signal, sys
import numpy as np
import torch

where = sys.argv[1]


def die():
    os.kill(os.getpid(), signal.SIGKILL)


def half_then_die(real, file_at):  # real's target file is its argument number file_at
    def write(*args, **kwargs):
        args, buf = list(args), io.BytesIO()
        target, args[file_at] = args[file_at], buf
        real(*args, **kwargs)
        data = buf.getvalue()
        with open(target, "wb") as fh:
            fh.write(data[: len(data) // 2])
        die()
    return write


real_rename = os.rename


def rename(src, dst, *args, **kwargs):
    if where == "before-swap":
        die()
    real_rename(src, dst, *args, **kwargs)
    if where == "mid-swap" and ".old-" in str(dst):
        die()


if where == "weights":
    torch.save = half_then_die(torch.save, 1)
elif where == "stats":
    np.savez = half_then_die(np.savez, 0)
else:
    os.rename = rename

from railwatch.cli import main

sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.slow
@pytest.mark.parametrize(("where", "previous"), [
    ("weights", False), ("weights", True), ("stats", True), ("before-swap", True),
    ("mid-swap", True)])
def test_train_killed_inside_save(where: str, previous: bool, work: Path,
                                  tmp_path: Path) -> None:
    out = tmp_path / "m"
    command = ["train", "--detector", "cnn-ae", "--data", str(work / "windows.npz"),
               "--config", str(TINY / "cnn-ae.yaml"), "--out", str(out)]
    if previous:
        assert main(["-q", *command, "--set", "seed=0"]) == 0
        before = (out / "weights.pt").read_bytes()
    run = Running([sys.executable, "-c", KILLER, where, "-q", *command, "--set", "seed=1"])
    run.wait_killed()
    pid = run.proc.pid
    left = leftovers(tmp_path, "m")
    if where == "mid-swap":
        # Between the renames: no model at --out; the previous one is named by the error.
        assert not out.exists() and f".m.old-{pid}" in left
        with pytest.raises(RailwatchError, match=rf"\.m\.old-{pid}: rename it to m"):
            load_detector(out)
        assert load_detector(tmp_path / f".m.old-{pid}").config.seed == 0  # type: ignore[attr-defined]
    elif previous:
        assert load_detector(out).config.seed == 0  # type: ignore[attr-defined]
        assert (out / "weights.pt").read_bytes() == before
    else:
        assert not out.exists()
    assert f".m.tmp-{pid}" in left  # killed inside save, its work half done beside --out

    # The next save works and clears what the dead process left.
    assert main(["-q", *command, "--set", "seed=2"]) == 0
    assert load_detector(out).config.seed == 2  # type: ignore[attr-defined]
    assert leftovers(tmp_path, "m") == []


# ----------------------------------------------------------------------------- save's steps
def _dead_pid() -> int:
    """The pid of a process that has exited (and been reaped)."""
    done = subprocess.Popen([sys.executable, "-c", "pass"])
    done.wait()
    return done.pid


@pytest.fixture(scope="module")
def fitted(work: Path):  # type: ignore[no-untyped-def]
    return create("cnn-ae", tiny_config("cnn-ae")).fit(load_windows(work / "windows.npz").X)


def test_save_clears_only_dead_writers_leftovers(fitted, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    dead, alive = _dead_pid(), os.getppid()
    out = tmp_path / "m"
    fitted.save(out)
    for pid in (dead, alive):
        for kind in ("tmp", "old"):
            shutil.copytree(out, tmp_path / f".m.{kind}-{pid}")
    (tmp_path / ".m.tmp-notapid").mkdir()
    (tmp_path / ".other.tmp-1").mkdir()
    fitted.save(out)
    assert leftovers(tmp_path, "m") == sorted([f".m.old-{alive}", f".m.tmp-{alive}",
                                               ".m.tmp-notapid"])
    assert (tmp_path / ".other.tmp-1").is_dir()
    load_detector(out)


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc to name fds")
def test_save_flushes_everything_before_the_swap(fitted, tmp_path: Path,  # type: ignore[no-untyped-def]
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """Every file, the new folder and (after the swap) the parent are fsync'ed; nothing is
    renamed into place before the files it holds are on disk."""
    out = tmp_path / "m"
    fitted.save(out)  # a previous model: the swap renames twice
    events: list[tuple[str, str]] = []
    real_fsync, real_rename = os.fsync, os.rename

    def fsync(fd: int) -> None:
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        real_fsync(fd)

    def rename(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        events.append(("rename", f"{src} -> {dst}"))
        real_rename(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "rename", rename)
    fitted.save(out)
    parent = os.path.realpath(tmp_path)  # as /proc names it
    tmp = os.path.join(parent, f".m.tmp-{os.getpid()}")
    synced = [what for kind, what in events if kind == "fsync"]
    renames = [i for i, (kind, _) in enumerate(events) if kind == "rename"]
    assert len(renames) == 2, events
    first_rename = renames[0]
    for name in sorted(p.name for p in out.iterdir()):
        assert ("fsync", f"{tmp}/{name}") in events[:first_rename], name
    assert ("fsync", tmp) in events[:first_rename]
    assert synced[-1] == parent, "the parent folder is flushed after the swap"
    assert events.index(("fsync", parent)) > renames[-1]
    assert leftovers(tmp_path, "m") == []
