"""``python -m benchmarks``: the index of the benchmarks; ``python -m benchmarks NAME [options]``
runs one (``python -m benchmarks NAME --help``: its options)."""

from __future__ import annotations

import ast
import importlib
import re
import sys
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).parent
#: Modules of this folder that are not benchmarks.
NOT_BENCHMARKS = {"__init__", "__main__", "common"}


@dataclass
class Benchmark:
    """What a benchmark module declares, read without importing it."""

    name: str
    summary: str  # the first sentence of its docstring
    needs: tuple[str, ...]
    page: str | None
    minutes: float


def declared(path: Path) -> Benchmark:
    """The declarations of one benchmark module (its docstring, ``NEEDS``, ``PAGE``,
    ``MINUTES``), read from its source."""
    tree = ast.parse(path.read_text())
    values: dict[str, object] = {}
    for node in tree.body:
        target = node.target if isinstance(node, ast.AnnAssign) else \
            node.targets[0] if isinstance(node, ast.Assign) and len(node.targets) == 1 else None
        if isinstance(target, ast.Name) and target.id in ("NEEDS", "PAGE", "MINUTES") \
                and node.value is not None:
            if target.id in values:
                raise SystemExit(f"benchmarks/{path.name} assigns {target.id} twice")
            values[target.id] = ast.literal_eval(node.value)
    missing = {"NEEDS", "PAGE", "MINUTES"} - set(values)
    if missing:
        raise SystemExit(f"benchmarks/{path.name} declares no {', '.join(sorted(missing))}: "
                         "every benchmark says what it needs, its page and its minutes")
    doc = " ".join((ast.get_docstring(tree) or "").split("\n\n")[0].split())
    summary = re.split(r"(?<=[.:])\s", doc)[0].rstrip(".:")
    return Benchmark(path.stem, summary, tuple(values["NEEDS"]), values["PAGE"],
                     float(values["MINUTES"]))


def benchmarks() -> dict[str, Benchmark]:
    """Every benchmark of this folder, by name."""
    return {p.stem: declared(p) for p in sorted(HERE.glob("*.py"))
            if p.stem not in NOT_BENCHMARKS}


def index(found: dict[str, Benchmark]) -> str:
    lines = ["python -m benchmarks NAME [options]   (make bench-NAME, hyphens for underscores;"
             " NAME --help: its options)", ""]
    for b in found.values():
        lines.append(f"{b.name:<24} ~{b.minutes:g} min  {b.page or '(prints a table)'}"
                     + (f"  [after {', '.join(b.needs)}]" if b.needs else ""))
        lines.append(f"    {b.summary[:100]}")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    found = benchmarks()
    if not argv or argv[0] in ("-h", "--help", "list"):
        print(index(found))
        return 0
    name = argv[0].replace("-", "_")
    if name not in found:
        print(f"error: no benchmark {argv[0]!r}: python -m benchmarks lists them "
              f"({', '.join(found)})", file=sys.stderr)
        return 2
    if found[name].needs:
        print(f"{name} reads the work folder of {', '.join(found[name].needs)}: run that first "
              "with the same --work (python -m benchmarks lists each one's needs)",
              file=sys.stderr)
    module = importlib.import_module(f"benchmarks.{name}")
    sys.argv = [f"python -m benchmarks {name}", *argv[1:]]
    return int(module.main() or 0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
