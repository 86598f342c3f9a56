"""benchmarks/ is a small package with one runner: every benchmark declares what the runner needs,
the index lists it, and none reaches into railwatch past its public API."""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FOLDER = REPO / "benchmarks"


@pytest.fixture
def runner(monkeypatch):  # type: ignore[no-untyped-def]
    monkeypatch.syspath_prepend(str(REPO))
    return importlib.import_module("benchmarks.__main__")


def test_every_benchmark_declares_needs_page_and_minutes(runner) -> None:  # type: ignore[no-untyped-def]
    found = runner.benchmarks()
    modules = {p.stem for p in FOLDER.glob("*.py")} - runner.NOT_BENCHMARKS
    assert set(found) == modules and len(found) >= 18
    for b in found.values():
        assert b.summary and b.minutes > 0
        assert set(b.needs) <= set(found) - {b.name}, b.name
        if b.page is not None:
            assert (REPO / b.page).is_file(), f"{b.name}: {b.page} is not committed"
    # What must run first has no cycle.
    done: set[str] = set()
    while len(done) < len(found):
        ready = {n for n, b in found.items() if n not in done and set(b.needs) <= done}
        assert ready, f"the needs of {sorted(set(found) - done)} form a cycle"
        done |= ready


def test_a_benchmark_without_declarations_is_refused(runner, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    bad = tmp_path / "bad.py"
    bad.write_text('"""Measures nothing."""\nNEEDS = ()\nPAGE = None\n')
    with pytest.raises(SystemExit, match="declares no MINUTES"):
        runner.declared(bad)
    bad.write_text('"""Measures nothing."""\nNEEDS = ()\nPAGE = None\nMINUTES = 1\nMINUTES = 2\n')
    with pytest.raises(SystemExit, match="assigns MINUTES twice"):
        runner.declared(bad)


def test_the_index_lists_every_benchmark_and_its_page(runner) -> None:  # type: ignore[no-untyped-def]
    index = (FOLDER / "README.md").read_text()
    for b in runner.benchmarks().values():
        assert f"| `{b.name}` |" in index, f"benchmarks/README.md does not list {b.name}"
        if b.page is not None:
            assert f"(../{b.page})" in index, f"benchmarks/README.md does not link {b.page}"


def _private_uses(tree: ast.AST) -> list[str]:
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            if node.attr.startswith("_") and not node.attr.startswith("__"):
                out.append(f"line {node.lineno}: .{node.attr}")
            if node.attr == "path" and isinstance(node.value, ast.Name) \
                    and node.value.id == "sys":
                out.append(f"line {node.lineno}: sys.path")
        if isinstance(node, ast.ImportFrom) and node.module:
            private = [a.name for a in node.names if a.name.startswith("_")]
            if node.module != "__future__" and (
                    any(p.startswith("_") for p in node.module.split(".")) or private):
                out.append(f"line {node.lineno}: from {node.module} import {private}")
        if isinstance(node, ast.ImportFrom) and node.level:
            out.append(f"line {node.lineno}: a relative import")
    return out


def test_no_benchmark_edits_sys_path_or_uses_a_private_name() -> None:
    found = {p.name: _private_uses(ast.parse(p.read_text())) for p in FOLDER.glob("*.py")}
    assert {name: uses for name, uses in found.items() if uses} == {}
    # The check can fail: the scripts as they were before the runner.
    old = ("import sys\nsys.path.insert(0, 'x')\nimport track_map as bench\n"
           "raw = det._raw_all(det._normalized(X))\nfrom railwatch.x import _load\n")
    assert len(_private_uses(ast.parse(old))) == 4


def test_every_benchmark_imports_as_part_of_the_package(runner) -> None:  # type: ignore[no-untyped-def]
    for name in runner.benchmarks():
        module = importlib.import_module(f"benchmarks.{name}")
        assert callable(module.main), name


def test_the_runner_lists_and_refuses_in_one_line() -> None:
    listed = subprocess.run([sys.executable, "-m", "benchmarks"], cwd=REPO, text=True,
                            capture_output=True, check=True).stdout
    assert "physics" in listed and "docs/results/physics/physics.md" in listed
    wrong = subprocess.run([sys.executable, "-m", "benchmarks", "no-such"], cwd=REPO, text=True,
                           capture_output=True)
    assert wrong.returncode == 2 and wrong.stderr.count("\n") == 1
    assert wrong.stderr.startswith("error: no benchmark 'no-such'")
    helped = subprocess.run([sys.executable, "-m", "benchmarks", "matched-filter-ridge", "--help"],
                            cwd=REPO, text=True, capture_output=True, check=True).stdout
    assert "--out" in helped


def test_the_physics_sweep_forms_events_as_detect_does(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """``physics.runs_above`` (the common false rate's events from a pass's scores) gives the
    events of ``detect``'s tracker, fed in blocks, on scores with runs near the merge gap."""
    monkeypatch.syspath_prepend(str(REPO))
    import numpy as np
    from benchmarks.physics import runs_above

    from railwatch.detection.stream import EventTracker

    rng = np.random.default_rng(0)
    t = np.arange(60000) / 2000.0
    point = rng.standard_normal(60000)
    for start in rng.integers(0, 59000, 40):  # bursts, some closer than 0.5 s
        point[start:start + rng.integers(1, 400)] += 6.0
    tracker = EventTracker(4.5, 1000, ("a",), ("g",))
    events = []
    for i in range(0, 60000, 3000):
        events += tracker.feed(point[i:i + 3000], point[i:i + 3000, None], t[i:i + 3000], None,
                               1 / 2000)
    events += tracker.close()
    got = runs_above(t, point, 4.5)
    assert len(got) == len(events) > 10
    for e, g in zip(events, got, strict=True):
        assert abs(e.start_s - g["start_s"]) < 1e-9 and abs(e.end_s - g["end_s"]) < 1e-9


def test_the_map_s_ablations_reach_the_code_the_map_runs(monkeypatch, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Each rule that `track_map_frame` and `track_map_fusion` switch off is one the fused map
    calls: the function switched is called by `fused_map` outside the switch and never inside it
    (a switch of a name the map does not call leaves two columns of a page equal, as the
    track map's re-layout did to both pages until 2026-12-07)."""
    monkeypatch.syspath_prepend(str(REPO))
    import numpy as np
    from benchmarks import track_map_frame, track_map_fusion

    from railwatch import trackmap as tm
    from railwatch.trackmap import fusion
    from support import profiles, scan_folder

    defects = np.array([600.0, 2100.0, 3700.0])
    xs, scores = profiles(5, defects, bump=4.0, seed=5)
    scan_folder(tmp_path, xs, scores, defects)
    passes = tm.read_scan(tmp_path)
    switches = {"keeps_move": lambda: track_map_frame.variant(0, passes),
                "profile_shifts": lambda: track_map_fusion.rules(2),
                "combine": lambda: track_map_fusion.rules(1),
                "calibrate": lambda: track_map_fusion.rules(0)}
    for name, switch in switches.items():
        calls: list[int] = []
        original = getattr(fusion, name)
        monkeypatch.setattr(fusion, name,
                            lambda *a, _f=original, _c=calls, **k: _c.append(1) or _f(*a, **k))
        with switch():
            tm.fused_map(passes)
        assert not calls, f"{name} is still called inside its switch"
        tm.fused_map(passes)
        assert calls, f"the map does not call fusion.{name}: the switch changes nothing"
