"""Print how the installed packages differ from a pip-compile lock (used by ``make test-latest``).

    python tools/lock_drift.py requirements.lock

Lists every locked package whose installed version differs, and those not installed, so that a
test run against the newest releases says which upgrades it is testing. Always exits 0.
"""

from __future__ import annotations

import re
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path


def pins(lock: Path) -> dict[str, str]:
    """``name -> version`` of every ``name==version`` line of a lock file."""
    found = {}
    for line in lock.read_text().splitlines():
        match = re.match(r"^([A-Za-z0-9_.\-]+)==([^\s;#]+)", line)
        if match:
            found[match[1].lower().replace("_", "-")] = match[2]
    return found


def main(lock: str) -> None:
    changed = []
    for name, locked in sorted(pins(Path(lock)).items()):
        try:
            installed = version(name)
        except PackageNotFoundError:
            installed = "not installed"
        if installed.split("+")[0] != locked.split("+")[0]:
            changed.append(f"  {name:<28} {locked:<16} -> {installed}")
    print(f"{len(changed)} package(s) differ from {lock}:" if changed
          else f"the newest releases are those of {lock}")
    print("\n".join(changed))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "requirements.lock")
