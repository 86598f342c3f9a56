"""train / score / evaluate / detectors through the command line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from railwatch.cli import main
from railwatch.detectors.registry import REGISTRY
from support import TINY


@pytest.fixture(scope="module")
def sets(tmp_path_factory) -> Path:  # type: ignore[no-untyped-def]
    d = tmp_path_factory.mktemp("sets")
    assert main(["-q", "generate", "--stage", "3", "--n", "200", "--out",
                 str(d / "train.npz")]) == 0
    assert main(["-q", "generate", "--stage", "3", "--n", "100", "--seed", "1", "--out",
                 str(d / "test.npz")]) == 0
    assert main(["-q", "generate", "--stage", "1", "--n", "20", "--out", str(d / "one.npz")]) == 0
    return d


def test_detectors_lists_every_registry_name_first(capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["detectors"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == list(REGISTRY)


def test_train_score_evaluate(sets, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    model, scores, metrics = tmp_path / "model", tmp_path / "scores.npz", tmp_path / "m.json"
    assert main(["-q", "train", "--detector", "cnn-ae", "--data", str(sets / "train.npz"),
                 "--out", str(model), "--config", str(TINY / "cnn-ae.yaml"),
                 "--set", "seed=3"]) == 0
    header = json.loads((model / "detector.json").read_text())
    assert header["detector"] == "cnn-ae" and header["config"]["seed"] == 3
    assert main(["-q", "score", "--model", str(model), "--data", str(sets / "test.npz"),
                 "--out", str(scores)]) == 0
    with np.load(scores) as f:
        assert f["instance"].shape == (100,) and f["point"].shape == (100, 200)
        assert f["channel"].shape == (100, 200, 2) and f["time_index"].shape == (100,)
    capsys.readouterr()
    assert main(["evaluate", "--data", str(sets / "test.npz"), "--scores", str(scores),
                 "--out", str(metrics)]) == 0
    printed = capsys.readouterr().out
    values = json.loads(metrics.read_text())
    for key in ("auc_instance", "auc_point", "auc_paper7", "ap_instance", "f1_fitted",
                "loc_time", "loc_channel"):
        assert key in printed and 0.0 <= values[key] <= 1.0


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["train", "--detector", "nope", "--data", "{s}/train.npz", "--out", "{t}/m"],
         "unknown detector 'nope'"),
        (["train", "--detector", "cnn-ae", "--data", "{s}/train.npz", "--out", "{t}/m",
          "--set", "epoch=1"], "unknown config key epoch"),
        (["train", "--detector", "cnn-ae", "--data", "{s}/train.npz", "--out", "{t}/m",
          "--set", "epochs"], "--set expects key=value"),
        (["train", "--detector", "cnn-ae", "--data", "{t}/missing.npz", "--out", "{t}/m"],
         "no such file"),
        (["train", "--detector", "cnn-ae", "--data", "{s}/train.npz", "--out", "{t}/m",
          "--config", "{t}/missing.yaml"], "no such config file"),
        (["score", "--model", "{t}/nomodel", "--data", "{s}/test.npz", "--out", "{t}/s.npz"],
         "no model directory"),
        (["score", "--model", "{s}", "--data", "{s}/test.npz", "--out", "{t}/s.npz"],
         "not a railwatch model directory"),
        (["evaluate", "--data", "{s}/test.npz", "--scores", "{s}/test.npz"],
         "is it a scores file"),
    ],
)
def test_errors_are_one_line(args, needle, sets, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    code = main([a.format(s=sets, t=tmp_path) for a in args])
    err = capsys.readouterr().err
    assert code != 0 and err.count("\n") == 1 and needle in err, err
    assert not (tmp_path / "m").exists() and not (tmp_path / "s.npz").exists()


def test_wrong_channels_and_corrupt_data(sets, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    model = tmp_path / "model"
    assert main(["-q", "train", "--detector", "cnn-ae", "--data", str(sets / "train.npz"),
                 "--out", str(model), "--config", str(TINY / "cnn-ae.yaml")]) == 0
    capsys.readouterr()
    out = tmp_path / "s.npz"
    assert main(["score", "--model", str(model), "--data", str(sets / "one.npz"),
                 "--out", str(out)]) == 1
    assert "expected 2 channels, got 1" in capsys.readouterr().err and not out.exists()
    bad = tmp_path / "nan.npz"
    with np.load(sets / "test.npz") as f:
        X = f["X"].copy()
    X[4, 10, 1] = np.nan
    np.savez(bad, X=X)
    assert main(["score", "--model", str(model), "--data", str(bad), "--out", str(out)]) == 1
    assert "NaN at window 4, step 10, channel 1" in capsys.readouterr().err
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    assert main(["score", "--model", str(model), "--data", str(tmp_path / "junk.npz"),
                 "--out", str(out)]) == 1
    assert "cannot read" in capsys.readouterr().err and not out.exists()
    # A failed retrain never damages the model that is there.
    before = (model / "weights.pt").read_bytes()
    assert main(["train", "--detector", "cnn-ae", "--data", str(bad), "--out", str(model)]) == 1
    assert (model / "weights.pt").read_bytes() == before
