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
    tail = round(0.1 * 2 / 60, 12)  # 0.1 per minute (pipeline.EVENTS_PER_MINUTE), 2-s windows
    assert threshold == GumbelNull(tail).fit(det.decision_scores_) == det.threshold_
    info = json.loads((folder / "model" / "recording.json").read_text())
    assert "threshold" not in info
    assert info["threshold_rule"] == "gumbel_null(tail=0.00333333)"
    rm = pipeline.load_recording_model(folder / "model")
    assert rm.threshold == threshold == rm.detector.threshold_


def test_a_model_saved_before_keeps_its_threshold(model, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Folders written before the threshold was stored once hold it in recording.json."""
    folder, det, _, threshold = model
    old = tmp_path / "old"
    layout = load_layout(folder / "train.layout.toml")
    rule = pipeline.event_threshold(Preparation(), pipeline.EVENTS_PER_MINUTE)
    info = json.loads(pipeline.recording_info(layout, Preparation(), rule)["recording.json"])
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


def test_a_model_that_uses_the_noise_floor(tmp_path: Path) -> None:
    """nuisance-glr trained on recordings gets their noise floor at training and, saved and
    read back, again in detect; it finds the run's defects."""
    write_run(tmp_path / "train.parquet", 2.0, seed=1, fs=2000.0)
    run, _, _ = write_run(tmp_path / "test.parquet", 1.0, seed=2, fs=2000.0)
    layout = load_layout(tmp_path / "train.layout.toml")
    trained = pipeline.train_on_recordings("nuisance-glr", {"null_windows": 2000},
                                           [tmp_path / "train.parquet"], layout,
                                           tmp_path / "model",
                                           progress=False)
    rm = pipeline.load_recording_model(tmp_path / "model")
    assert rm.detector.fitted_uses() == ["noise_floor"] and rm.threshold == trained.threshold
    rec = Recording(tmp_path / "test.parquet", load_layout(tmp_path / "test.layout.toml"))
    peaks = np.array([e.peak_s for e in pipeline.detect(rm.detector, rec, rm.preparation).events])
    centres = np.array([d["center_s"] for d in run.defects])
    found = np.mean([np.any(np.abs(peaks - c) <= 0.25) for c in centres])
    false = sum(not np.any(np.abs(centres - p) <= 0.25) for p in peaks)
    assert found >= 0.8 and false <= 4, (found, false)  # 1 minute; 0.6 per minute of null
