"""ONNX export of a trained detector's network, and scoring with onnxruntime.

``export_onnx`` writes the network part of a deep detector (normalised windows (B, T, C) -> the raw
outputs its scoring uses, e.g. reconstruction error and attention features) as one ONNX graph
with a dynamic batch axis. Everything else the model needs travels inside the same file as
metadata (``railwatch`` key): the detector's header and config, its fitted statistics (input
normalisation, score statistics, threshold) and, for a model trained on recordings, its layout,
preparation and event threshold. ``load_onnx`` rebuilds the detector around an onnxruntime
session: the same Python scoring, localisation and streaming work on it, with the network run by
onnxruntime instead of PyTorch. Attention maps (``extras``) are not exported.

Agreement with PyTorch is tested to 1e-3 (relative and absolute) on instance and point scores
(:data:`TOLERANCE`); detectors without a network (matched filter, oracle) cannot be exported.
"""

from __future__ import annotations

import base64
import io
import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from railwatch.atomic import atomic_path
from railwatch.detectors.base import (
    Detector,
    TorchDetector,
    config_from_dict,
    load_detector,
)
from railwatch.errors import RailwatchError

META_KEY = "railwatch"
TOLERANCE = 1e-3  # relative and absolute, on scores standardised by their training statistics
OPSET = 17


class _RawGraph(torch.nn.Module):
    """The exported function: normalised windows -> the raw outputs, in a fixed key order."""

    def __init__(self, detector: TorchDetector, keys: list[str]) -> None:
        super().__init__()
        self.detector = detector
        self.model = detector.model_  # registers the weights
        self.keys = keys

    def forward(self, windows: torch.Tensor) -> tuple[torch.Tensor, ...]:
        out = self.detector.raw(windows)
        return tuple(out[k].float() for k in self.keys)


def export_onnx(model: str | os.PathLike[str] | Detector, out: str | os.PathLike[str],
                batch_size: int = 32) -> Path:
    """Write ``model`` (a trained detector or its folder) as a self-contained ONNX file."""
    folder = Path(model) if not isinstance(model, Detector) else None
    det = load_detector(folder) if folder is not None else model
    assert isinstance(det, Detector)
    if not isinstance(det, TorchDetector):
        raise RailwatchError(f"{det.registry_name or type(det).__name__} has no neural network "
                             "to export: only the deep detectors export to ONNX")
    det._check_fitted()
    det.model_.eval()
    example = torch.zeros(batch_size, det.n_steps_, det.n_channels_)
    with torch.no_grad():
        keys = list(det.raw(example.to(det.device_)).keys())
    graph = _RawGraph(det, keys).to("cpu").eval()
    det.device_ = torch.device("cpu")
    buf = io.BytesIO()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(graph, (example,), buf,  # type: ignore[arg-type]
                              input_names=["windows"], output_names=keys,
                              dynamic_axes={"windows": {0: "batch"},
                                            **{k: {0: "batch"} for k in keys}},
                              opset_version=OPSET, dynamo=False)
    except Exception as e:  # noqa: BLE001 - any exporter failure is one line for the user
        raise RailwatchError(f"{det.registry_name} does not export to ONNX: "
                             f"{type(e).__name__}: {' '.join(str(e).split())[:200]}") from None
    import onnx

    proto = onnx.load_from_string(buf.getvalue())
    meta = proto.metadata_props.add()
    meta.key, meta.value = META_KEY, json.dumps(_metadata(det, keys, folder))
    out = Path(out)
    with atomic_path(out) as tmp:
        onnx.save(proto, tmp)
    return out


def _metadata(det: Detector, keys: list[str], folder: Path | None) -> dict[str, Any]:
    from dataclasses import asdict

    stats = io.BytesIO()
    np.savez(stats, **det.stats_)  # type: ignore[arg-type]
    recording = None
    if folder is not None and (folder / "recording.json").is_file():
        recording = json.loads((folder / "recording.json").read_text())
    return {
        "detector": det.registry_name or type(det).__name__,
        "config": asdict(det.config), "n_steps": det.n_steps_, "n_channels": det.n_channels_,
        "outputs": keys, "stats": base64.b64encode(stats.getvalue()).decode(),
        "input": "windows (batch, n_steps, n_channels) float32, normalised per channel as "
                 "(x - stats.input_mean) / stats.input_std where the detector normalises",
        "recording": recording,
    }


class OnnxBackend:
    """Runs the exported graph: a normalised batch -> raw outputs (the TorchDetector hook)."""

    def __init__(self, path: Path, keys: list[str], threads: int | None = None) -> None:
        import onnxruntime as ort

        options = ort.SessionOptions()
        if threads:
            options.intra_op_num_threads = threads
            options.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(path), options,
                                            providers=["CPUExecutionProvider"])
        self.keys = keys

    def __call__(self, batch: NDArray[Any]) -> dict[str, NDArray[Any]]:
        outs = self.session.run(self.keys, {"windows": batch.astype(np.float32, copy=False)})
        return dict(zip(self.keys, outs, strict=True))


def read_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    import onnx

    path = Path(path)
    if not path.is_file():
        raise RailwatchError(f"no such ONNX file: {path}")
    try:
        proto = onnx.load(str(path), load_external_data=False)
    except Exception as e:  # noqa: BLE001
        raise RailwatchError(f"{path} is not a readable ONNX file ({type(e).__name__})") from None
    found = {p.key: p.value for p in proto.metadata_props}
    if META_KEY not in found:
        raise RailwatchError(f"{path} was not exported by railwatch (no '{META_KEY}' metadata)")
    return dict(json.loads(found[META_KEY]))


def load_onnx(path: str | os.PathLike[str], threads: int | None = None) -> Detector:
    """A detector whose network runs in onnxruntime; scores like the PyTorch original."""
    from railwatch.detectors.registry import class_for

    meta = read_metadata(path)
    cls = class_for(meta["detector"])
    det = cls(config_from_dict(cls.Config, meta["config"]))
    det.registry_name = meta["detector"]
    det.n_steps_, det.n_channels_ = int(meta["n_steps"]), int(meta["n_channels"])
    with np.load(io.BytesIO(base64.b64decode(meta["stats"])), allow_pickle=False) as f:
        det.stats_ = {k: f[k] for k in f.files}
    det.threshold_ = float(det.stats_["threshold"])
    det.device_ = torch.device("cpu")  # type: ignore[attr-defined]
    det.backend_ = OnnxBackend(Path(path), list(meta["outputs"]), threads)  # type: ignore[attr-defined]
    return det
