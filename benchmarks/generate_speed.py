"""Time `railwatch generate --n 100000` for every stage (file write included) and print a
Markdown table with the date, CPU and thread count. Run: `make bench-generate-speed`."""

from __future__ import annotations

import datetime
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from railwatch.machine import cpu_name

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = None
MINUTES = 3


def main() -> None:
    n = 100_000
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for stage in range(1, 9):
            out = Path(tmp) / f"s{stage}.npz"
            start = time.perf_counter()
            subprocess.run([sys.executable, "-m", "railwatch.cli", "-q", "generate", "--stage",
                            str(stage), "--n", str(n), "--out", str(out)], check=True)
            seconds = time.perf_counter() - start
            rows.append((stage, seconds, out.stat().st_size / 2**20))
            out.unlink()
    print(f"`make bench-generate-speed` on {datetime.date.today()}, {cpu_name()}, "
          f"{len(os.sched_getaffinity(0))} cores; n = {n:,} windows per stage, wall time of the "
          "whole command (start-up and the .npz write included).\n")
    print("| stage | seconds | file (MiB) |\n|---|---|---|")
    for stage, seconds, mib in rows:
        print(f"| {stage} | {seconds:.1f} | {mib:.0f} |")


if __name__ == "__main__":
    main()
