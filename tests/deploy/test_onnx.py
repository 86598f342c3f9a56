"""ONNX export: every deep detector exports, and onnxruntime scores match PyTorch's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from railwatch.cli import main
from railwatch.deploy.onnx import TOLERANCE, export_onnx, load_onnx
from railwatch.detectors import create, names
from railwatch.detectors.training import TorchDetector
from railwatch.errors import RailwatchError
from railwatch.synthetic import generate
from support import tiny_config as tiny

DEEP = [n for n in names() if issubclass(type(create(n)), TorchDetector)]


@pytest.fixture(scope="module")
def data() -> tuple[np.ndarray, np.ndarray]:
    return generate(5, 96, seed=0).X, generate(5, 40, seed=1).X


@pytest.mark.parametrize("name", DEEP)
def test_onnx_scores_match_pytorch(name: str, data, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    train, test = data
    det = create(name, tiny(name)).fit(train)
    path = export_onnx(det, tmp_path / f"{name}.onnx")
    onnx = load_onnx(path)
    a, b = det.score(test), onnx.score(test)
    np.testing.assert_allclose(b.instance, a.instance, rtol=TOLERANCE, atol=TOLERANCE)
    np.testing.assert_allclose(b.point, a.point, rtol=TOLERANCE, atol=TOLERANCE)
    assert onnx.threshold_ == det.threshold_  # stored, not recomputed: exact
    # Predictions agree wherever the score is not within the tolerance of the threshold (there
    # onnxruntime's other kernels may tip a window either way).
    clear = np.abs(a.instance - det.threshold_) > TOLERANCE * (1 + abs(det.threshold_))
    np.testing.assert_array_equal(onnx.predict(test)[clear], det.predict(test)[clear])
    assert clear.mean() > 0.9
    with pytest.raises(RailwatchError, match="expected 6 channels"):
        onnx.score(test[..., :2])


def test_export_cli_and_errors(data, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    train, _ = data
    model = tmp_path / "m"
    create("cnn-ae", tiny("cnn-ae")).fit(train).save(model)
    assert main(["-q", "export", "--model", str(model), "--out", str(tmp_path / "m.onnx")]) == 0
    assert (tmp_path / "m.onnx").stat().st_size > 1000
    create("matched-filter", tiny("matched-filter")).fit(train).save(tmp_path / "mf")
    for args, message in [
        (["--model", str(tmp_path / "mf"), "--out", str(tmp_path / "mf.onnx")],
         "no neural network"),
        (["--model", str(model), "--out", str(tmp_path / "m.pt")], "ending in .onnx"),
        (["--model", str(tmp_path / "none"), "--out", str(tmp_path / "x.onnx")],
         "no model directory"),
    ]:
        assert main(["export", *args]) == 1
        assert message in capsys.readouterr().err
    assert not (tmp_path / "mf.onnx").exists()
    (tmp_path / "junk.onnx").write_text("junk")
    with pytest.raises(RailwatchError, match="not a readable ONNX file"):
        load_onnx(tmp_path / "junk.onnx")
