"""The benchmark run end to end through the CLI, resumability, presets and the Ray executor."""

from __future__ import annotations

import json
from html.parser import HTMLParser
from pathlib import Path

import pytest

from railwatch.bench.presets import load_preset
from railwatch.cli import main
from railwatch.errors import RailwatchError

OUTPUTS = ("results.json", "table1.md", "table1.csv", "table2.md", "localization.md",
           "auc_vs_stage.png", "auc_point_vs_stage.png", "score_hist.png", "stages.png",
           "report.html")
SMOKE = ["-q", "bench", "--preset", "smoke", "--stages", "1,3", "--detectors",
         "cnn-ae,matched-filter"]


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory) -> Path:  # type: ignore[no-untyped-def]
    out = tmp_path_factory.mktemp("bench") / "smoke"
    assert main([*SMOKE, "--out", str(out)]) == 0
    return out


def test_smoke_run_writes_every_output(smoke_run: Path) -> None:
    for name in OUTPUTS:
        assert (smoke_run / name).stat().st_size > 0, name
    assert not list((smoke_run / "cache" / "models").glob("*/fit_residual.npz"))
    results = json.loads((smoke_run / "results.json").read_text())
    cells = results["cells"]
    assert {(c["stage"], c["detector"]) for c in cells} == {
        (s, d) for s in (1, 3) for d in ("cnn-ae", "matched-filter")}
    for c in cells:
        for key in ("auc_instance", "auc_point", "auc_paper7", "ap_instance", "f1_fitted",
                    "loc_time", "fit_s", "score_s", "config", "environment", "n_channels"):
            assert key in c, key
        assert 0 <= c["auc_instance"] <= 1
        assert (c["loc_channel"] is None) == (c["stage"] == 1)
    table1 = (smoke_run / "table1.md").read_text()
    assert "paper 0.960" in table1 and "(drop)" in table1  # cnn-ae's paper value, stage drops
    assert "paper 67.1" in (smoke_run / "table2.md").read_text()


def test_second_run_recomputes_nothing(smoke_run: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    cell_files = sorted((smoke_run / "cells").glob("*"))
    before = {p: p.stat().st_mtime_ns for p in cell_files}
    assert main([*SMOKE[1:], "--out", str(smoke_run)]) == 0  # not quiet: the summary prints
    out, err = capsys.readouterr()
    assert "4 reused" in err and "report:" in out
    assert {p: p.stat().st_mtime_ns for p in cell_files} == before


def test_scoring_variants_share_one_training(tmp_path) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "shared"
    assert main(["-q", "bench", "--preset", "smoke", "--stages", "1", "--detectors",
                 "aft-attention,aft-reconstruction,aft-combined,aft-reconstruction+glr,"
                 "cnn-ae,cnn-ae+glr", "--out", str(out)]) == 0
    cells = json.loads((out / "results.json").read_text())["cells"]
    assert [c["trained_by"] for c in cells] == ["aft-attention"] * 4 + ["cnn-ae"] * 2
    assert len({c["threshold"] for c in cells}) == 6  # each mode fits its own threshold
    models = list((out / "cache" / "models").iterdir())
    assert len(models) == 2
    # a +glr row reuses each: the training windows' residual is kept beside it for the row's
    # threshold; without such a row (the smoke run's cnn-ae) nothing is kept
    assert all((m / "fit_residual.npz").is_file() for m in models)
    assert cells[1]["fit_s"] >= cells[0]["fit_s"]  # the shared training's time is counted
    assert cells[5]["fit_s"] >= cells[4]["fit_s"]


def test_retime_measures_scoring_again_and_keeps_the_aucs(smoke_run: Path, tmp_path) -> None:  # type: ignore[no-untyped-def]
    before = {(c["stage"], c["detector"]): c
              for c in json.loads((smoke_run / "results.json").read_text())["cells"]}
    # re-timing a part (Table II's stages) rewrites the report of everything the folder holds
    part = [*SMOKE[:5], "1", *SMOKE[6:]]
    assert main([*part, "--out", str(smoke_run), "--retime"]) == 0
    after = json.loads((smoke_run / "results.json").read_text())["cells"]
    assert {(c["stage"], c["detector"]) for c in after} == set(before)
    assert {c["stage"] for c in after if c.get("score_retimed")} == {1}
    assert main([*SMOKE, "--out", str(smoke_run), "--retime"]) == 0
    after = json.loads((smoke_run / "results.json").read_text())["cells"]
    for c in after:
        old = before[(c["stage"], c["detector"])]
        assert c["auc_instance"] == old["auc_instance"] and c["fit_s"] == old["fit_s"]
        assert c["score_retimed"] and c["score_s"] > 0
    assert main([*SMOKE, "--out", str(tmp_path / "empty"), "--retime"]) == 1  # nothing finished


class _Collector(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.stack: list[str] = []
        self.images: list[str] = []
        self.tables = 0

    def handle_starttag(self, tag, attrs):  # type: ignore[no-untyped-def]
        if tag not in ("img", "meta", "br"):
            self.stack.append(tag)
        if tag == "img":
            self.images.append(dict(attrs)["src"])
        self.tables += tag == "table"

    def handle_endtag(self, tag):  # type: ignore[no-untyped-def]
        assert self.stack and self.stack[-1] == tag, (self.stack[-3:], tag)
        self.stack.pop()


def test_report_is_valid_and_self_contained(smoke_run: Path) -> None:
    html = (smoke_run / "report.html").read_text()
    parser = _Collector()
    parser.feed(html)
    assert parser.stack == []  # every element closed, properly nested
    assert parser.tables >= 5 and len(parser.images) >= 4
    assert all(src.startswith("data:image/png;base64,") for src in parser.images)
    assert "http://" not in html and "https://" not in html  # opens offline


def test_preset_errors() -> None:
    with pytest.raises(RailwatchError, match="unknown preset"):
        load_preset("gigantic")
    with pytest.raises(RailwatchError, match="stages must be 1-8"):
        load_preset("smoke", stages=(0, 9))
    with pytest.raises(RailwatchError, match="unknown detector"):
        load_preset("smoke", detectors=("nope",))


def test_every_preset_file_loads() -> None:
    from railwatch.bench.presets import PRESET_DIR

    files = sorted(PRESET_DIR.glob("*.yaml"))
    assert {p.stem for p in files} >= {"smoke", "quick", "standard"}
    for p in files:
        load_preset(p)  # validates every detector override against its config


def test_bad_bench_arguments(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["bench", "--preset", "smoke", "--out", str(tmp_path / "x"),
                 "--stages", "1,a"]) == 1
    assert "comma" in capsys.readouterr().err
    assert main(["bench", "--preset", "smoke", "--out", str(tmp_path / "x"),
                 "--address", "1.2.3.4:6379"]) == 1
    assert "--executor ray" in capsys.readouterr().err


@pytest.fixture
def one_thread():  # type: ignore[no-untyped-def]
    """torch and BLAS on one thread in this process, as in every Ray task (restored after)."""
    import torch
    from threadpoolctl import threadpool_limits

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    with threadpool_limits(1):
        yield
    torch.set_num_threads(before)


#: How far a metric of the same cell may differ between executors. Both sides run on one thread
#: (``one_thread``), so on one machine they agree bit for bit; what this allows for is the
#: platform choosing other kernels in another process. That changes the order of float32 sums,
#: so scores agree to a few ulps (checked below to 1e-5), and an AUC moves only where two scores
#: are that close: one swapped pair moves the instance AUC by 1/(P N) = 1/(13 x 115) = 6.7e-4
#: at the smoke size and the point AUC by ~4e-8. A real executor fault (another seed, other data
#: or config) moves these AUCs by more than 0.01.
METRIC_TOLERANCE = 1e-3


@pytest.mark.slow
def test_ray_executor_matches_local(tmp_path, one_thread) -> None:  # type: ignore[no-untyped-def]
    pytest.importorskip("ray")
    import numpy as np
    import ray

    args = ["-q", "bench", "--preset", "smoke", "--stages", "1,3", "--detectors",
            "oracle,matched-filter,cnn-ae"]
    assert main([*args, "--out", str(tmp_path / "local")]) == 0
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        assert main([*args, "--executor", "ray", "--out", str(tmp_path / "ray")]) == 0
    finally:
        ray.shutdown()
    metrics = ("auc_instance", "auc_point", "auc_paper7", "ap_instance", "f1_fitted",
               "loc_time", "loc_channel")

    def read(p: Path) -> dict:  # type: ignore[type-arg]
        cells = json.loads((p / "results.json").read_text())["cells"]
        return {(c["stage"], c["detector"]): c for c in cells}

    local, remote = read(tmp_path / "local"), read(tmp_path / "ray")
    assert local.keys() == remote.keys() and len(local) == 6
    for key, cell in local.items():
        assert cell["config"] == remote[key]["config"], key
        for m in metrics:
            if cell[m] is None:
                assert remote[key][m] is None, (key, m)
            else:
                assert remote[key][m] == pytest.approx(cell[m], abs=METRIC_TOLERANCE), (key, m)
        name = f"stage{key[0]}-{key[1]}-seed0.npz"
        with np.load(tmp_path / "local" / "cells" / name) as a, \
                np.load(tmp_path / "ray" / "cells" / name) as b:
            np.testing.assert_allclose(b["instance"], a["instance"], rtol=1e-5, atol=1e-6)
