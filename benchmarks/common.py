"""What the benchmarks share: running the CLI in a child process (timed, its peak memory, on one
core if asked), the command line a page names, reading a CSV, and matching events to a run's
truth."""

from __future__ import annotations

import csv
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: Environment of a child process held to one thread.
ONE_CORE = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


@dataclass
class Ran:
    """A finished ``railwatch`` child process."""

    wall_s: float  # wall-clock seconds of the whole command (start-up included)
    peak_mib: float  # its peak resident memory
    stderr: str  # what it reported ("" unless captured)


def railwatch(*args: str, one_core: bool = False, quiet: bool = True,
              capture: bool = False) -> Ran:
    """Run ``railwatch ARGS`` in a child process: pinned to core 0 with one thread when
    ``one_core``, with ``-q`` when ``quiet``, its standard output and error captured (and the
    error returned) when ``capture``; raises on a non-zero exit."""
    env = {**os.environ, **(ONE_CORE if one_core else {})}
    if one_core:  # a timed run compiles no Python source: an installed railwatch has its
        env.pop("PYTHONDONTWRITEBYTECODE", None)  # bytecode (with it set, 1.5 of 6 s went there)
    with tempfile.NamedTemporaryFile(suffix=".txt") as peak_file:
        cmd = ["/usr/bin/time", "-f", "%M", "-o", peak_file.name, sys.executable, "-m",
               "railwatch.cli", *(["-q"] if quiet else []), *args]
        if one_core:
            cmd = ["taskset", "-c", "0", *cmd]
        start = time.perf_counter()
        done = subprocess.run(cmd, env=env, check=True, capture_output=capture, text=True)
        wall = time.perf_counter() - start
        peak_kib = float(Path(peak_file.name).read_text().split()[-1])
    return Ran(wall, peak_kib / 1024, done.stderr if capture else "")


def real_time_factor(said: str) -> float:
    """The real-time factor ``railwatch detect`` reports in its last line ("... scanned in
    4.0 s (150x real time) ..."): reading, preparing and scoring, not start-up; NaN if absent."""
    found = re.search(r"\((\d+)x real time\)", said)
    return float(found.group(1)) if found else float("nan")


def command(module: str) -> str:
    """The command that runs the benchmark ``module`` (its ``__name__``) with this run's
    options, as a page names it."""
    name = module.rpartition(".")[2]
    return shlex.join(["python", "-m", "benchmarks", name, *sys.argv[1:]])


def read_csv(path: Path) -> list[dict[str, Any]]:
    """The rows of a CSV file with a header."""
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def match(events: list[dict[str, Any]], truth: Path, tol: float = 0.25,
          ) -> tuple[float, int, float]:
    """Events of a synthesised run against its ``.defects.csv``: the share of defects with an
    event's peak within ``tol`` s, the events with no defect there, and the share of the events
    at a defect that name its channel."""
    rows = read_csv(truth)
    centers = np.array([float(r["center_s"]) for r in rows])
    peaks = np.array([e["peak_s"] for e in events])
    found = [np.any(np.abs(peaks - c) <= tol) for c in centers]
    false = [not np.any(np.abs(centers - p) <= tol) for p in peaks]
    right_channel = []
    for e in events:
        j = int(np.argmin(np.abs(centers - e["peak_s"])))
        if abs(centers[j] - e["peak_s"]) <= tol:
            right_channel.append(rows[j]["channel"] == e["channel"])
    channel = float(np.mean(right_channel)) if right_channel else float("nan")
    return float(np.mean(found)), int(sum(false)), channel
