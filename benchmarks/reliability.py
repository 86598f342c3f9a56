"""Run the fault and fuzz tests and write what they tried into docs/results/reliability.md.

    python -m benchmarks reliability            # make bench-reliability

Counts per test file: test cases (each fault case is one), Hypothesis examples run (passing and
failing, from ``--hypothesis-show-statistics``), failures and seconds; with the command, date,
CPU and commit. docs/reliability.md explains the promises these tests hold railwatch to.
"""

from __future__ import annotations

import datetime
import re
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

from railwatch.machine import cpu_name
from railwatch.report.pages import write_markdown

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ()
PAGE = "docs/results/reliability.md"
MINUTES = 3

ROOT = Path(__file__).parents[1]
FILES = {
    "tests/bench/test_faults.py": "bench killed mid-cell and mid-write, damaged cells, one run "
                                  "per folder",
    "tests/test_kill.py": "train and detect killed mid-run and mid-save",
    "tests/detectors/test_model_folder_faults.py": "tampered model folders and .onnx files",
    "tests/recordings/test_readers_fuzz.py": "readers fuzzed: random bytes, truncations, random "
                                             "CSV/Parquet/HDF5/MAT content",
    "tests/test_progress.py": "progress lines without a terminal",
}
STATS = re.compile(r"(\d+) passing, (\d+) failing")


def main() -> int:
    files = [f for f in FILES if (ROOT / f).exists()]
    with tempfile.TemporaryDirectory() as tmp:
        junit = Path(tmp) / "junit.xml"
        cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
               "--hypothesis-show-statistics", f"--junitxml={junit}", *files]
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
        cases: dict[str, list[ET.Element]] = defaultdict(list)
        for case in ET.parse(junit).iter("testcase"):
            path = (case.get("classname") or "").replace(".", "/") + ".py"
            cases[path].append(case)
    examples: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    current = None
    for line in proc.stdout.splitlines():
        head = re.match(r"^(tests/\S+\.py)::\S+:$", line.strip())
        if head:
            current = head[1]
        found = STATS.search(line)
        if found and current:
            examples[current][0] += int(found[1])
            examples[current][1] += int(found[2])
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    rows = ["| test file | what it tries | test cases | fuzz examples | failures | seconds |",
            "|---|---|---|---|---|---|"]
    totals = [0, 0, 0, 0.0]
    for f in files:
        group = cases.get(f, [])
        failed = sum(1 for c in group if c.find("failure") is not None
                     or c.find("error") is not None)
        seconds = sum(float(c.get("time") or 0) for c in group)
        passing, failing = examples.get(f, [0, 0])
        rows.append(f"| `{f}` | {FILES[f]} | {len(group)} | {passing + failing:,} | {failed} | "
                    f"{seconds:.0f} |")
        for i, v in enumerate((len(group), passing + failing, failed, seconds)):
            totals[i] += v
    rows.append(f"| **all** | | **{totals[0]}** | **{totals[1]:,}** | **{totals[2]}** | "
                f"**{totals[3]:.0f}** |")
    summary = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else "(no output)"
    lines = [
        "# Reliability: fault and fuzz tests, last run",
        "",
        f"`make bench-reliability` (`python -m benchmarks reliability`), "
        f"{datetime.date.today().isoformat()}, commit {commit}, {cpu_name()}, "
        "2 cores. What is promised and how each promise is tested: "
        "[docs/reliability.md](../reliability.md).",
        "",
        *rows,
        "",
        f"pytest: {summary}",
    ]
    write_markdown(ROOT / "docs" / "results" / "reliability.md", lines)
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
