"""The recordings pipeline as a library: windows from runs, a model fitted and saved with its
event threshold stored once, read back (also as saved before), detection."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from railwatch.detection import pipeline
from railwatch.detectors import create
from railwatch.recordings.layout import load_layout
from railwatch.recordings.prepare import Preparation
from railwatch.recordings.readers import Recording
from railwatch.scoring.thresholds import GumbelNull
from railwatch.synthetic.run_files import write_run
from support import tiny_config


@pytest.fixture(scope="module")
def model(tmp_path_factory):  # type: ignore[no-untyped-def]
    folder = tmp_path_factory.mktemp("pipeline")
    write_run(folder / "train.csv", 1.0, seed=1, fs=200.0)
    write_run(folder / "test.csv", 0.5, seed=2, fs=200.0)
    layout = load_layout(folder / "train.layout.toml")
    prep = Preparation()
    X = pipeline.training_windows([Recording(folder / "train.csv", layout)], prep)
    det = create("matched-filter", tiny_config("matched-filter"))
    threshold = pipeline.fit_recording_model(det, X, layout, prep, folder / "model")
    return folder, det, X, threshold


def test_windows_of_a_run(model) -> None:  # type: ignore[no-untyped-def]
    _, _, X, _ = model
    # one minute at 100 Hz after resampling, 2-s windows every 1 s
    assert X.shape == (59, 200, 6) and X.dtype == np.float32


def test_the_event_threshold_is_stored_once(model) -> None:  # type: ignore[no-untyped-def]
    folder, det, _, threshold = model
    assert threshold == GumbelNull(0.02).fit(det.decision_scores_) == det.threshold_
    info = json.loads((folder / "model" / "recording.json").read_text())
    assert "threshold" not in info and info["threshold_rule"] == "gumbel_null(tail=0.02)"
    rm = pipeline.load_recording_model(folder / "model")
    assert rm.threshold == threshold == rm.detector.threshold_


def test_a_model_saved_before_keeps_its_threshold(model, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Folders written before the threshold was stored once hold it in recording.json."""
    folder, det, _, threshold = model
    old = tmp_path / "old"
    layout = load_layout(folder / "train.layout.toml")
    info = json.loads(pipeline.recording_info(layout, Preparation())["recording.json"])
    det.save(old, extra_files={"recording.json": json.dumps({**info, "threshold": 7.5})})
    assert pipeline.load_recording_model(old).threshold == 7.5 != threshold


def test_detect_a_run(model) -> None:  # type: ignore[no-untyped-def]
    folder, _, _, threshold = model
    rm = pipeline.load_recording_model(folder / "model")
    rec = Recording(folder / "test.csv", load_layout(folder / "test.layout.toml"))
    result = pipeline.detect(rm.detector, rec, rm.preparation, rm.threshold)
    assert result.threshold == threshold and abs(result.duration_s - 30.0) < 0.01
    assert all(e.score > threshold for e in result.events)
    assert result.trace.time and len(result.trace.time) == len(result.trace.score)
