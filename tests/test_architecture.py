"""The import graph of ``src/railwatch`` against the architecture (``docs/architecture.md``).

Run it alone with ``pytest tests/test_architecture.py``. Every ``import`` statement counts, also
one inside a function or under ``TYPE_CHECKING``: a lazy import is still a dependency.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from functools import cache
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"

#: Layers, lowest first: a module may import modules of lower layers, and modules of its own
#: layer only within its own package. The data flows down this list: data sources and file
#: formats -> detectors (which call the scoring library) -> evaluation -> the workflows that apply
#: a detector -> reports -> the benchmark -> the command line.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("railwatch", "railwatch.errors", "railwatch.atomic", "railwatch.progress",
     "railwatch.mapping_files", "railwatch.machine", "railwatch.parallel"),
    ("railwatch.windows", "railwatch.recordings"),  # file formats; recordings, the data source
    ("railwatch.scoring",),  # the scoring library
    ("railwatch.synthetic",),  # synthetic windows and runs (runs written as recordings)
    ("railwatch.physics",),  # the vehicle-track world: passes written as recordings, twins
    ("railwatch.detectors",),
    ("railwatch.evaluation", "railwatch.evaluation.metrics"),
    ("railwatch.deploy",),  # a detector exported to, and loaded from, ONNX
    ("railwatch.detection",),  # detection on recordings: train, detect, stream
    ("railwatch.trackmap",),  # repeated passes: scan, the scan folder, alignment, fusion, maps
    ("railwatch.report",),  # tables, figures, the benchmark's report, the detection plot
    ("railwatch.bench",),
    ("railwatch.cli",),
)

#: Reports draw what the data and the detectors produced; they never produce data themselves.
FORBIDDEN = (("railwatch.report", "railwatch.synthetic"),)

#: Edges against the rules that a later step of the re-layout removes (the re-layout issue):
#: each is listed so that it cannot grow unnoticed, and removing one must remove it here.
KNOWN: set[tuple[str, str]] = set()


def _module_name(path: Path) -> str:
    parts = path.relative_to(SRC).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


@cache
def graph() -> dict[str, set[str]]:
    """railwatch module -> the railwatch modules it imports."""
    files = {_module_name(p): p for p in SRC.joinpath("railwatch").rglob("*.py")}
    edges: dict[str, set[str]] = {}
    for mod, path in files.items():
        package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                deps.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*up, base] if base else up)
                for alias in node.names:  # "from pkg import submodule" is the submodule
                    sub = f"{base}.{alias.name}"
                    deps.add(sub if sub in files else base)
        edges[mod] = {d for d in deps if d in files and d != mod}
    return edges


def layer_of(module: str) -> tuple[int, str]:
    """The layer of ``module`` and the entry that placed it (the longest matching prefix)."""
    best = (-1, "")
    for i, entries in enumerate(LAYERS):
        for entry in entries:
            if (module == entry or module.startswith(entry + ".")) and len(entry) > len(best[1]):
                best = (i, entry)
    assert best[0] >= 0, f"{module} is in no layer: add it to LAYERS and docs/architecture.md"
    return best


def _strongly_connected(edges: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's components of more than one module (the cycles)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def violations() -> set[tuple[str, str]]:
    found = set()
    for mod, deps in graph().items():
        (lm, em) = layer_of(mod)
        for dep in deps:
            (ld, ed) = layer_of(dep)
            same_package = em == ed or mod.rpartition(".")[0] == dep.rpartition(".")[0]
            if ld > lm or (ld == lm and not same_package):
                found.add((mod, dep))
            if any(mod.startswith(a) and (dep == b or dep.startswith(b + "."))
                   for a, b in FORBIDDEN):
                found.add((mod, dep))
    return found


def test_the_graph_is_read() -> None:
    edges = graph()
    assert "railwatch.detectors.api" in edges["railwatch.detectors.registry"]
    # "from railwatch.detectors import model_folder" is an edge to the submodule
    assert "railwatch.detectors.model_folder" in edges["railwatch.detectors.api"]
    assert "railwatch.scoring.glr" in edges["railwatch.scoring.residual"]


def test_no_import_cycle() -> None:
    assert _strongly_connected(graph()) == []


def test_no_cycle_between_packages() -> None:
    packages: dict[str, set[str]] = {}
    for mod, deps in graph().items():
        top = ".".join(mod.split(".")[:2])
        packages.setdefault(top, set()).update(".".join(d.split(".")[:2]) for d in deps)
    for top in packages:
        packages[top].discard(top)
    packages = {k: {d for d in v if d in packages} for k, v in packages.items()}
    assert _strongly_connected(packages) == []


def test_no_package_sits_on_two_layers() -> None:
    layers: dict[str, set[int]] = {}
    for mod in graph():
        top = ".".join(mod.split(".")[:2])
        layers.setdefault(top, set()).add(layer_of(mod)[0])
    assert {top: sorted(ls) for top, ls in layers.items() if len(ls) > 1} == {}


def test_cycle_finder_finds_a_cycle() -> None:
    edges = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _strongly_connected(edges) == [["a", "b", "c"]]


def test_no_import_against_the_layers() -> None:
    new = sorted(violations() - KNOWN)
    assert not new, "imports against the layers of docs/architecture.md: " + ", ".join(
        f"{a} -> {b}" for a, b in new)


def test_known_exceptions_still_exist() -> None:
    gone = sorted(KNOWN - violations())
    assert not gone, "fixed, remove from KNOWN: " + ", ".join(f"{a} -> {b}" for a, b in gone)


def test_api_scoring_and_evaluation_do_not_import_torch() -> None:
    """Naming, creating and listing detectors, the scoring library and the metrics work without
    torch: it is imported when a deep detector is built, loaded or trained."""
    code = ("import sys; import railwatch.detectors as d, railwatch.scoring.residual, "
            "railwatch.scoring.reduce, railwatch.evaluation.metrics; d.create('oracle'); "
            "d.names(); print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_reports_ask_the_registry_not_the_name() -> None:
    """``report/`` never compares a detector's name with a literal of the registry's own rows
    (the ceiling, a reference, a ``+glr`` suffix): it asks ``registry.role`` and
    ``registry.variant_of``."""
    literals = {"oracle", "matched-filter", "+glr"}
    found = []
    for path in SRC.joinpath("railwatch", "report").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Compare):
                parts = [node.left, *node.comparators]
                if any(isinstance(p, ast.Constant) and p.value in literals for p in parts):
                    found.append(f"{path.name}:{node.lineno}")
            elif isinstance(node, ast.Name) and node.id == "GLR_SUFFIX":
                found.append(f"{path.name}:{node.lineno}")
    assert not found, found
