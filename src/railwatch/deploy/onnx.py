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
import hashlib
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
from railwatch.detectors import model_folder
from railwatch.detectors.api import Detector
from railwatch.detectors.registry import load_detector
from railwatch.detectors.training import TorchDetector
from railwatch.errors import RailwatchError, naming, one_line

META_KEY = "railwatch"
#: Metadata key of the SHA-256 of the graph and the ``railwatch`` metadata, written at export:
#: bytes changed on disk (or a graph or metadata swapped in) are refused when the file is loaded.
CHECKSUM_KEY = "railwatch.sha256"
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
                batch_size: int = 32, verify: bool = True) -> Path:
    """Write ``model`` (a trained detector or its folder) as a self-contained ONNX file.

    A detector given as an object is left on its device. ``verify`` loads the written file
    back (:func:`load_onnx`), so that a file that would not load onboard is removed now, with
    a one-line error, instead of being found out there.
    """
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
    device = det.device_
    graph = _RawGraph(det, keys).to("cpu").eval()  # the exporter traces on the CPU
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
    finally:
        det.model_.to(device)
        det.device_ = device
    import onnx

    proto = onnx.load_from_string(buf.getvalue())
    text = json.dumps(_metadata(det, keys, folder))
    for key, value in ((META_KEY, text), (CHECKSUM_KEY, _checksum(proto, text))):
        meta = proto.metadata_props.add()
        meta.key, meta.value = key, value
    out = Path(out)
    with atomic_path(out) as tmp:
        onnx.save(proto, tmp)
    if verify:
        try:
            load_onnx(out)
        except RailwatchError:
            out.unlink(missing_ok=True)  # no file that looks exported but does not load
            raise
    return out


def _metadata(det: Detector, keys: list[str], folder: Path | None) -> dict[str, Any]:
    from dataclasses import asdict

    stats = io.BytesIO()
    np.savez(stats, **det.stats_)  # type: ignore[arg-type]
    recording = model_folder.read_recording(folder) if folder is not None else None
    return {
        "detector": det.registry_name or type(det).__name__,
        "config": asdict(det.config), "n_steps": det.n_steps_, "n_channels": det.n_channels_,
        "outputs": keys, "stats": base64.b64encode(stats.getvalue()).decode(),
        "input": "windows (batch, n_steps, n_channels) float32, normalised per channel as "
                 "(x - stats.input_mean) / stats.input_std where the detector normalises",
        "recording": recording,
    }


class OnnxNetwork:
    """Runs the exported graph: a normalised batch -> raw outputs (the
    :class:`railwatch.detectors.training.Network` protocol, as the torch module).

    ``model`` is the file's content when the caller has read it already (it is then not read a
    second time). Failures of onnxruntime, creating the session or running it, are one-line
    :class:`RailwatchError` messages naming the file.
    """

    def __init__(self, path: Path, keys: list[str], threads: int | None = None,
                 model: bytes | None = None) -> None:
        import onnxruntime as ort

        self.path = Path(path)
        options = ort.SessionOptions()
        options.log_severity_level = 4  # errors reach the user as one line, not as a log
        if threads:
            options.intra_op_num_threads = threads
            options.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(model if model is not None else str(path),
                                                options, providers=["CPUExecutionProvider"])
        except Exception as e:  # noqa: BLE001 - onnxruntime raises its own exception types
            raise RailwatchError(f"{self.path} is damaged: onnxruntime cannot load its network "
                                 f"({_ort_message(e)})") from None
        self.keys = keys

    def check(self, n_steps: int, n_channels: int) -> None:
        """The graph takes ``windows`` (batch, n_steps, n_channels) and gives ``keys``."""
        inputs = {i.name: i.shape for i in self.session.get_inputs()}
        outputs = {o.name for o in self.session.get_outputs()}
        if list(inputs) != ["windows"]:
            raise RailwatchError(f"{self.path}: the network takes {', '.join(inputs) or 'nothing'}"
                                 ", not windows: it was not exported by railwatch or is damaged")
        shape = list(inputs["windows"])
        if len(shape) != 3 or any(isinstance(got, int) and got != want
                                  for got, want in zip(shape[1:], (n_steps, n_channels),
                                                       strict=True)):
            raise RailwatchError(f"{self.path}: the network takes windows of shape {shape}, its "
                                 f"metadata says (batch, {n_steps}, {n_channels}): it is damaged")
        missing = [k for k in self.keys if k not in outputs]
        if missing:
            raise RailwatchError(f"{self.path}: the network has no output {missing[0]!r} named "
                                 "in its metadata: it is damaged")

    def __call__(self, batch: NDArray[Any]) -> dict[str, NDArray[Any]]:
        try:
            outs = self.session.run(self.keys, {"windows": batch.astype(np.float32, copy=False)})
        except Exception as e:  # noqa: BLE001
            raise RailwatchError(f"{self.path}: onnxruntime failed to run the network "
                                 f"({_ort_message(e)})") from None
        return dict(zip(self.keys, outs, strict=True))


def _ort_message(e: BaseException) -> str:
    return f"{type(e).__name__}: {one_line(e)[:200]}"


def _checksum(proto: Any, text: str) -> str:
    """SHA-256 of the graph (as serialised by protobuf) and of the ``railwatch`` metadata."""
    digest = hashlib.sha256(proto.graph.SerializeToString())
    digest.update(text.encode())
    return digest.hexdigest()


def _read(path: Path) -> tuple[bytes, Any, dict[str, Any]]:
    """The file's bytes, its parsed model and its ``railwatch`` metadata, checked."""
    import onnx

    if not path.is_file():
        raise RailwatchError(f"no such ONNX file: {path}")
    try:
        data = path.read_bytes()
    except OSError as e:
        raise RailwatchError(f"cannot read {path}: {e.strerror or one_line(e)}") from None
    try:
        proto = onnx.load_from_string(data)
    except Exception as e:  # noqa: BLE001
        raise RailwatchError(f"{path} is not a readable ONNX file ({type(e).__name__}): it is "
                             "damaged or not an ONNX model") from None
    found = {p.key: p.value for p in proto.metadata_props}
    if META_KEY not in found:
        raise RailwatchError(f"{path} was not exported by railwatch, or is damaged (no "
                             f"'{META_KEY}' metadata): export it with 'railwatch export'")
    digest = found.get(CHECKSUM_KEY)  # files exported before checksums have none
    if digest is not None and digest != _checksum(proto, found[META_KEY]):
        raise RailwatchError(f"{path} is damaged: its network or metadata differs from what was "
                             "exported (SHA-256 mismatch): export the model again")
    try:
        meta = json.loads(found[META_KEY])
    except ValueError as e:
        raise RailwatchError(f"{path}: its '{META_KEY}' metadata is damaged (not JSON: "
                             f"{one_line(e)})") from None
    if not isinstance(meta, dict):
        raise RailwatchError(f"{path}: its '{META_KEY}' metadata is damaged (not a table)")
    return data, proto, meta


def read_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The ``railwatch`` metadata of an exported file (checked against its checksum)."""
    return _read(Path(path))[2]


def load_onnx(path: str | os.PathLike[str], threads: int | None = None) -> Detector:
    """A detector whose network runs in onnxruntime; scores like the PyTorch original.

    A damaged file (truncated, bytes changed, metadata edited, another graph) is a one-line
    :class:`RailwatchError` naming it; the returned detector has scored a window.
    """
    from railwatch.detectors.registry import class_for

    path = Path(path)
    data, _, meta = _read(path)
    try:
        cls = class_for(meta["detector"])
        if not issubclass(cls, TorchDetector):
            raise RailwatchError(f"its metadata names {meta['detector']}, which has no network")
        keys = meta["outputs"]
        if not isinstance(keys, list) or not keys or not all(isinstance(k, str) for k in keys):
            raise RailwatchError("its metadata lists no outputs")
        stats = base64.b64decode(meta["stats"], validate=True)
        with np.load(io.BytesIO(stats), allow_pickle=False) as f:
            arrays = {k: f[k] for k in f.files}

        def attach(det: Detector) -> None:
            assert isinstance(det, TorchDetector)
            network = OnnxNetwork(path, keys, threads, model=data)
            network.check(det.n_steps_, det.n_channels_)
            det.device_ = torch.device("cpu")
            det.network_ = network

        det = cls.restored(meta["detector"], meta["config"], meta, arrays, "its metadata",
                           attach)
    except RailwatchError as e:
        raise naming(str(path), e) from None
    except Exception as e:  # noqa: BLE001 - damaged metadata, whatever the exception
        raise RailwatchError(f"{path}: its '{META_KEY}' metadata is damaged "
                             f"({type(e).__name__}: {one_line(e)[:160]})") from None
    return det
