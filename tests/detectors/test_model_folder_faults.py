"""Damaged model folders and ONNX files: one line on stderr, exit code 1, never a traceback.

A model folder (``detector.json``, ``stats.npz``, ``weights.pt``, ``recording.json``) or an
exported ``.onnx`` file may be truncated by a full disk, flipped by a failing flash card, replaced
by the wrong file or edited by hand. Each such fault is a :class:`RailwatchError` from
``load_detector`` / ``load_onnx`` / ``load_recording_model`` and, through the command line
(``score``, ``detect``, ``export``), exactly one line ``railwatch: error: ...`` and exit code 1:
not ``internal error``, not a traceback, and no output file.
"""

from __future__ import annotations

import base64
import io
import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from railwatch.cli import main
from railwatch.deploy.onnx import CHECKSUM_KEY, META_KEY, load_onnx, read_metadata
from railwatch.detection.pipeline import load_recording_model
from railwatch.detectors.registry import load_detector
from railwatch.errors import RailwatchError
from support import TINY

DEEP = ("cnn-ae", "aft-attention")
DETECTORS = (*DEEP, "matched-filter")
#: For each detector, a registered detector of another class (for "detector.json names another").
OTHER = {"cnn-ae": "lstm-ed", "aft-attention": "cnn-ae", "matched-filter": "oracle"}


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 30-s recording with its layout, and 12 windows of the same shape to score."""
    d = tmp_path_factory.mktemp("faults")
    assert main(["-q", "generate-run", "--minutes", "0.5", "--seed", "1",
                 "--out", str(d / "run.parquet")]) == 0
    assert main(["-q", "generate", "--stage", "5", "--n", "12", "--seed", "3",
                 "--out", str(d / "windows.npz")]) == 0
    return d


@pytest.fixture(scope="module")
def models(work: Path) -> Callable[[str], Path]:
    """``models(name)``: a model folder trained on the recording (tiny config), made once."""
    made: dict[str, Path] = {}

    def get(name: str) -> Path:
        if name not in made:
            out = work / "models" / name
            out.parent.mkdir(exist_ok=True)
            assert main(["-q", "train", "--detector", name, "--recordings",
                         str(work / "run.parquet"), "--layout", str(work / "run.layout.toml"),
                         "--config", str(TINY / f"{name}.yaml"), "--out", str(out)]) == 0
            made[name] = out
        return made[name]

    return get


@pytest.fixture(scope="module")
def onnx_file(work: Path, models: Callable[[str], Path]) -> Path:
    out = work / "cnn-ae.onnx"
    assert main(["-q", "export", "--model", str(models("cnn-ae")), "--out", str(out)]) == 0
    return out


# ----------------------------------------------------------------------------- folder faults
def _header(folder: Path, change: Callable[[dict[str, Any]], Any]) -> None:
    path = folder / "detector.json"
    header = json.loads(path.read_text())
    change(header)
    path.write_text(json.dumps(header))


def _stats(folder: Path, change: Callable[[dict[str, np.ndarray]], Any]) -> None:
    with np.load(folder / "stats.npz") as f:
        stats = {k: f[k] for k in f.files}
    change(stats)
    np.savez(folder / "stats.npz", **stats)  # type: ignore[arg-type]


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _random(path: Path, size: int | None = None) -> None:
    n = size if size is not None else max(path.stat().st_size, 64)
    path.write_bytes(np.random.default_rng(7).bytes(n))


def _flip(path: Path, at: float = 0.5, count: int = 4) -> None:
    data = bytearray(path.read_bytes())
    i = int(len(data) * at)
    for k in range(count):
        data[i + 7 * k] ^= 0x5A
    path.write_bytes(bytes(data))


def _drop_stat(stats: dict[str, np.ndarray]) -> None:
    """Remove the detector's own statistic (not the threshold, not the input normalisation)."""
    own = sorted(k for k in stats if k not in ("threshold", "input_mean", "input_std"))
    del stats[own[0]]


def _resize_weights(folder: Path) -> None:
    state = torch.load(folder / "weights.pt", weights_only=True)
    key = next(k for k, v in state.items() if v.ndim >= 1 and v.shape[0] > 1)
    state[key] = state[key][:1]
    torch.save(state, folder / "weights.pt")


def _recording(folder: Path, change: Callable[[dict[str, Any]], Any]) -> None:
    path = folder / "recording.json"
    info = json.loads(path.read_text())
    change(info)
    path.write_text(json.dumps(info))


def _five_channels(info: dict[str, Any]) -> None:
    info["layout"]["channels"].pop()
    info["layout"]["groups"].pop()


Fault = Callable[[Path, Callable[[str], Path]], Any]
# name -> (the fault, only for deep detectors, found by load_detector (else load_recording_model))
FOLDER_FAULTS: dict[str, tuple[Fault, bool, bool]] = {
    "weights-random-bytes": (lambda m, _: _random(m / "weights.pt"), True, True),
    "weights-truncated": (lambda m, _: _truncate(m / "weights.pt"), True, True),
    "weights-empty": (lambda m, _: (m / "weights.pt").write_bytes(b""), True, True),
    "weights-deleted": (lambda m, _: (m / "weights.pt").unlink(), True, True),
    "weights-bytes-flipped": (lambda m, _: _flip(m / "weights.pt", 0.6), True, True),
    "weights-of-another-detector": (
        lambda m, models: shutil.copy(
            models("aft-attention" if m.name == "cnn-ae" else "cnn-ae") / "weights.pt",
            m / "weights.pt"), True, True),
    "weights-wrong-shape": (lambda m, _: _resize_weights(m), True, True),
    "weights-not-a-state-dict": (lambda m, _: torch.save([1, 2, 3], m / "weights.pt"), True, True),
    "stats-truncated": (lambda m, _: _truncate(m / "stats.npz"), False, True),
    "stats-random-bytes": (lambda m, _: _random(m / "stats.npz"), False, True),
    "stats-bytes-flipped": (lambda m, _: _flip(m / "stats.npz", 0.3), False, True),
    "stats-deleted": (lambda m, _: (m / "stats.npz").unlink(), False, True),
    "stats-missing-threshold": (lambda m, _: _stats(m, lambda s: s.pop("threshold")), False, True),
    "stats-missing-input-mean": (
        lambda m, _: _stats(m, lambda s: s.pop("input_mean")), False, True),
    "stats-missing-own-key": (lambda m, _: _stats(m, _drop_stat), False, True),
    "stats-wrong-shape": (
        lambda m, _: _stats(m, lambda s: s.update(input_std=s["input_std"][:3])), False, True),
    "stats-threshold-not-scalar": (
        lambda m, _: _stats(m, lambda s: s.update(threshold=np.ones(3))), False, True),
    "stats-pickled-object": (
        lambda m, _: _stats(m, lambda s: s.update(threshold=np.array([{}], dtype=object))),
        False, True),
    "header-invalid-json": (
        lambda m, _: (m / "detector.json").write_text('{"format": "railwatch-det'), False, True),
    "header-empty": (lambda m, _: (m / "detector.json").write_text(""), False, True),
    "header-deleted": (lambda m, _: (m / "detector.json").unlink(), False, True),
    "header-not-an-object": (lambda m, _: (m / "detector.json").write_text("[1, 2]"), False, True),
    "header-other-format": (
        lambda m, _: _header(m, lambda h: h.update(format="something-else")), False, True),
    "header-newer-format-version": (
        lambda m, _: _header(m, lambda h: h.update(format_version=99)), False, True),
    "header-format-version-text": (
        lambda m, _: _header(m, lambda h: h.update(format_version="2")), False, True),
    "header-another-detector": (
        lambda m, _: _header(m, lambda h: h.update(detector=OTHER[m.name])), False, True),
    "header-unknown-detector": (
        lambda m, _: _header(m, lambda h: h.update(detector="isolation-forest")), False, True),
    "header-missing-n-steps": (lambda m, _: _header(m, lambda h: h.pop("n_steps")), False, True),
    "header-n-channels-changed": (
        lambda m, _: _header(m, lambda h: h.update(n_channels=3)), False, True),
    "header-n-channels-text": (
        lambda m, _: _header(m, lambda h: h.update(n_channels="six")), False, True),
    "config-unknown-key": (
        lambda m, _: _header(m, lambda h: h["config"].update(no_such_key=1)), False, True),
    "config-wrong-type": (
        lambda m, _: _header(m, lambda h: h["config"].update(batch_size="big")), False, True),
    "config-not-an-object": (
        lambda m, _: _header(m, lambda h: h.update(config=[1, 2])), False, True),
    "config-missing": (lambda m, _: _header(m, lambda h: h.pop("config")), False, True),
    "recording-invalid-json": (
        lambda m, _: (m / "recording.json").write_text("{not json"), False, False),
    "recording-missing-layout": (lambda m, _: _recording(m, lambda r: r.pop("layout")), False,
                                 False),
    "recording-threshold-text": (
        lambda m, _: _recording(m, lambda r: r.update(threshold="high")), False, False),
    "recording-preparation-unknown-key": (
        lambda m, _: _recording(m, lambda r: r["preparation"].update(speed=1)), False, False),
    "recording-window-text": (
        lambda m, _: _recording(m, lambda r: r["preparation"].update(window_s="two")),
        False, False),
    "recording-layout-five-channels": (lambda m, _: _recording(m, _five_channels), False, False),
}


#: Faults that only the checksums in detector.json find: the damaged file still loads and
#: scores (flipped bytes inside the weights), or ``railwatch detect`` does not check what it
#: reads from recording.json (see ``detection.pipeline.load_recording_model``).
#: Faults the command line (the first set) or the loading functions (the second) miss without
#: the checksums; those of recording.json are for ``detection.pipeline.load_recording_model``.
def _cases(commands: tuple[str, ...], sealed: bool = True) -> list[Any]:
    """(detector, fault, command, sealed) for every fault that applies. ``sealed=False``: the
    model as saved before detector.json recorded checksums (the fault is found otherwise)."""
    out = []
    for case, (_, deep_only, _) in FOLDER_FAULTS.items():
        for name in DETECTORS:
            if deep_only and name not in DEEP:
                continue
            for command in commands:
                if command == "export" and name not in DEEP:
                    continue  # the matched filter never exports
                if command != "detect" and case.startswith("recording-"):
                    continue  # only detect reads recording.json
                if not sealed and case == "weights-bytes-flipped":
                    continue  # may well load: without the checksum, nothing tells
                out.append(pytest.param(name, case, command, sealed,
                                        id=f"{name}-{case}-{command}"
                                           + ("" if sealed else "-unsealed")))
    return out


def damaged(name: str, case: str, models: Callable[[str], Path], tmp_path: Path,
            sealed: bool = True) -> Path:
    folder = tmp_path / name
    shutil.copytree(models(name), folder)
    if not sealed:
        _header(folder, lambda h: h.pop("sha256"))
    FOLDER_FAULTS[case][0](folder, models)
    return folder


def assert_one_line_error(rc: int, err: str) -> str:
    lines = err.splitlines()
    assert rc == 1, err
    assert len(lines) == 1, err
    assert lines[0].startswith("railwatch: error: "), err
    assert "internal error" not in err and "Traceback" not in err
    return lines[0]


def run_command(command: str, model: Path, work: Path, tmp_path: Path) -> tuple[int, Path]:
    if command == "score":
        out = tmp_path / "scores.npz"
        args = ["score", "--model", str(model), "--data", str(work / "windows.npz")]
    elif command == "detect":
        out = tmp_path / "events.csv"
        args = ["detect", "--model", str(model), "--recording", str(work / "run.parquet")]
    else:
        out = tmp_path / "model.onnx"
        args = ["export", "--model", str(model)]
    return main(["-q", *args, "--out", str(out)]), out


@pytest.mark.parametrize(("name", "case", "command", "sealed"),
                         _cases(("score", "detect", "export")) + _cases(("detect",), False))
def test_damaged_folder_is_one_line_error(name: str, case: str, command: str, sealed: bool,
                                          work: Path, models: Callable[[str], Path],
                                          tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    model = damaged(name, case, models, tmp_path, sealed)
    capsys.readouterr()
    rc, out = run_command(command, model, work, tmp_path)
    assert_one_line_error(rc, capsys.readouterr().err)
    assert not out.exists()


@pytest.mark.parametrize(("name", "case", "sealed"), [
    pytest.param(*p.values[:2], p.values[3], marks=p.marks, id=p.id.replace("-detect", ""))
    for p in _cases(("detect",)) + _cases(("detect",), False)])
def test_damaged_folder_raises_railwatch_error(name: str, case: str, sealed: bool, work: Path,
                                               models: Callable[[str], Path],
                                               tmp_path: Path) -> None:
    model = damaged(name, case, models, tmp_path, sealed)
    by_load_detector = FOLDER_FAULTS[case][2]
    with pytest.raises(RailwatchError) as caught:
        if by_load_detector:
            load_detector(model)
        else:
            load_recording_model(model)
    message = str(caught.value)
    assert "\n" not in message
    assert str(model) in message, message  # the message says which model


def test_intact_models_still_work(work: Path, models: Callable[[str], Path], tmp_path: Path,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    """The faults above are the only reason for the errors: the undamaged folders work."""
    for name in DETECTORS:
        for command in ("score", "detect", "export") if name in DEEP else ("score", "detect"):
            rc, out = run_command(command, models(name), work, tmp_path)
            assert rc == 0, capsys.readouterr().err
            assert out.exists()
            out.unlink()


def test_missing_folder_after_interrupted_save_names_the_old_model(
        models: Callable[[str], Path], tmp_path: Path) -> None:
    """A save killed between moving the old model aside and moving the new one in leaves only
    ``.NAME.old-PID``: loading the missing folder says where the previous model is."""
    old = tmp_path / ".m.old-999999999"
    shutil.copytree(models("cnn-ae"), old)
    with pytest.raises(RailwatchError, match=r"no model directory .*\.m\.old-999999999"):
        load_detector(tmp_path / "m")


# ----------------------------------------------------------------------------- ONNX faults
def _edit_meta(path: Path, change: Callable[[dict[str, Any]], Any] | None = None,
               raw: str | None = None, drop: bool = False) -> None:
    import onnx

    proto = onnx.load(str(path))
    props = {p.key: p.value for p in proto.metadata_props}
    del proto.metadata_props[:]
    if not drop:
        if raw is None:
            meta = json.loads(props[META_KEY])
            assert change is not None
            change(meta)
            raw = json.dumps(meta)
        props[META_KEY] = raw
    else:
        props.pop(META_KEY)
    for key, value in props.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(proto, str(path))


def _meta_stats(change: Callable[[dict[str, np.ndarray]], Any]) -> Callable[[dict[str, Any]], Any]:
    def edit(meta: dict[str, Any]) -> None:
        with np.load(io.BytesIO(base64.b64decode(meta["stats"]))) as f:
            stats = {k: f[k] for k in f.files}
        change(stats)
        buf = io.BytesIO()
        np.savez(buf, **stats)  # type: ignore[arg-type]
        meta["stats"] = base64.b64encode(buf.getvalue()).decode()

    return edit


def _foreign_onnx(path: Path) -> None:
    """A valid ONNX graph of the same input and output names, not exported by railwatch."""
    import onnx

    keys = read_metadata(path)["outputs"]

    class Net(torch.nn.Module):
        def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
            return tuple(x * (i + 1) for i in range(len(keys)))

    buf = io.BytesIO()
    torch.onnx.export(Net(), (torch.zeros(2, 200, 6),), buf,  # type: ignore[arg-type]
                      input_names=["windows"],
                      output_names=keys, dynamic_axes={"windows": {0: "batch"}},
                      opset_version=17, dynamo=False)
    onnx.save(onnx.load_from_string(buf.getvalue()), str(path))


def _graph_swapped(path: Path) -> None:
    """Another graph (of the same names) under the railwatch metadata of this file."""
    import onnx

    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    _foreign_onnx(path)
    proto = onnx.load(str(path))
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(proto, str(path))


def _weights_flipped(path: Path) -> None:
    """Flip bytes inside the largest weight tensor: the file still parses and runs."""
    data = bytearray(path.read_bytes())
    import onnx

    proto = onnx.load(str(path))
    raw = max((t.raw_data for t in proto.graph.initializer), key=len)
    start = bytes(data).find(raw)
    assert start > 0
    for k in range(0, min(len(raw), 64), 8):
        data[start + k + 3] ^= 0x40
    path.write_bytes(bytes(data))


ONNX_FAULTS: dict[str, Callable[[Path], Any]] = {
    "truncated": _truncate,
    "random-bytes": _random,
    "empty": lambda p: p.write_bytes(b""),
    "bytes-flipped-25": lambda p: _flip(p, 0.25),
    "bytes-flipped-50": lambda p: _flip(p, 0.5),
    "bytes-flipped-75": lambda p: _flip(p, 0.75),
    "weights-flipped": _weights_flipped,
    "no-railwatch-metadata": lambda p: _edit_meta(p, drop=True),
    "foreign-onnx": _foreign_onnx,
    "graph-swapped": _graph_swapped,
    "metadata-invalid-json": lambda p: _edit_meta(p, raw='{"detector": "cnn-'),
    "metadata-not-an-object": lambda p: _edit_meta(p, raw="[1, 2, 3]"),
    "metadata-missing-stats": lambda p: _edit_meta(p, lambda m: m.pop("stats")),
    "metadata-missing-detector": lambda p: _edit_meta(p, lambda m: m.pop("detector")),
    "metadata-missing-config": lambda p: _edit_meta(p, lambda m: m.pop("config")),
    "metadata-missing-outputs": lambda p: _edit_meta(p, lambda m: m.pop("outputs")),
    "metadata-missing-n-channels": lambda p: _edit_meta(p, lambda m: m.pop("n_channels")),
    "metadata-unknown-detector": lambda p: _edit_meta(p, lambda m: m.update(detector="x")),
    "metadata-another-detector": lambda p: _edit_meta(p, lambda m: m.update(detector="mscred")),
    "metadata-config-unknown-key": lambda p: _edit_meta(p, lambda m: m["config"].update(z=1)),
    "metadata-config-wrong-type": lambda p: _edit_meta(
        p, lambda m: m["config"].update(batch_size="big")),
    "metadata-n-channels-changed": lambda p: _edit_meta(p, lambda m: m.update(n_channels=3)),
    "metadata-n-steps-changed": lambda p: _edit_meta(p, lambda m: m.update(n_steps=150)),
    "metadata-outputs-renamed": lambda p: _edit_meta(p, lambda m: m.update(outputs=["nope"])),
    "metadata-stats-base64-broken": lambda p: _edit_meta(
        p, lambda m: m.update(stats=m["stats"][:-7] + "!!")),
    "metadata-stats-not-npz": lambda p: _edit_meta(
        p, lambda m: m.update(stats=base64.b64encode(b"not an npz file").decode())),
    "metadata-stats-missing-threshold": lambda p: _edit_meta(
        p, _meta_stats(lambda s: s.pop("threshold"))),
    "metadata-stats-missing-own-key": lambda p: _edit_meta(p, _meta_stats(_drop_stat)),
    "metadata-recording-damaged": lambda p: _edit_meta(
        p, lambda m: m.update(recording={"layout": 5})),
    "metadata-recording-missing": lambda p: _edit_meta(p, lambda m: m.update(recording=None)),
}


#: Without the checksum (a file exported before it was written), these may still load and run.
ONNX_SEALED_ONLY = ("bytes-flipped-50", "bytes-flipped-75", "weights-flipped", "graph-swapped")


def _unseal(path: Path) -> None:
    import onnx

    proto = onnx.load(str(path))
    kept = [(p.key, p.value) for p in proto.metadata_props if p.key != CHECKSUM_KEY]
    assert len(kept) < len(proto.metadata_props)
    del proto.metadata_props[:]
    for key, value in kept:
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(proto, str(path))


def damaged_onnx(case: str, onnx_file: Path, tmp_path: Path, sealed: bool = True) -> Path:
    path = tmp_path / "model.onnx"
    shutil.copy(onnx_file, path)
    if not sealed:
        _unseal(path)
    ONNX_FAULTS[case](path)
    return path


def _onnx_cases(load: bool) -> list[Any]:
    return [pytest.param(case, sealed, id=case + ("" if sealed else "-unsealed"))
            for sealed in (True, False) for case in ONNX_FAULTS
            if (sealed or case not in ONNX_SEALED_ONLY)
            and not (load and case.startswith("metadata-recording"))]  # for detect only


ONNX_EXPORT_WARNINGS = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@ONNX_EXPORT_WARNINGS
@pytest.mark.parametrize(("case", "sealed"), _onnx_cases(load=False))
def test_damaged_onnx_is_one_line_error(case: str, sealed: bool, work: Path, onnx_file: Path,
                                        tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    path = damaged_onnx(case, onnx_file, tmp_path, sealed)
    events = tmp_path / "events.csv"
    capsys.readouterr()
    rc = main(["-q", "detect", "--model", str(path), "--recording", str(work / "run.parquet"),
               "--out", str(events)])
    assert_one_line_error(rc, capsys.readouterr().err)
    assert not events.exists()


@ONNX_EXPORT_WARNINGS
@pytest.mark.parametrize(("case", "sealed"), _onnx_cases(load=True))
def test_damaged_onnx_raises_railwatch_error(case: str, sealed: bool, onnx_file: Path,
                                             tmp_path: Path) -> None:
    path = damaged_onnx(case, onnx_file, tmp_path, sealed)
    with pytest.raises(RailwatchError) as caught:
        load_onnx(path)
    assert "\n" not in str(caught.value)
    assert str(path) in str(caught.value)  # the message names the file


def test_intact_onnx_still_works(work: Path, onnx_file: Path, tmp_path: Path) -> None:
    """Rewritten by onnx.save (the checksum survives), or without a checksum: still loads."""
    copy, unsealed = tmp_path / "copy.onnx", tmp_path / "unsealed.onnx"
    shutil.copy(onnx_file, copy)
    _edit_meta(copy, lambda m: None)
    shutil.copy(onnx_file, unsealed)
    _unseal(unsealed)
    for path in (onnx_file, copy, unsealed):
        assert main(["-q", "detect", "--model", str(path), "--recording",
                     str(work / "run.parquet"), "--out", str(tmp_path / "events.csv")]) == 0
        assert load_onnx(path).threshold_ > 0
