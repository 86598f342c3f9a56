"""The scores file of ``railwatch score``: written, read back, evaluated; one-line errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from railwatch.detectors import create
from railwatch.errors import RailwatchError
from railwatch.evaluation.metrics import evaluate_scores
from railwatch.evaluation.scores_file import evaluate_files, read_scores, write_scores
from railwatch.scoring.reduce import localize
from railwatch.synthetic import generate
from support import tiny_config


@pytest.fixture(scope="module")
def scored(tmp_path_factory):  # type: ignore[no-untyped-def]
    folder = tmp_path_factory.mktemp("scores")
    train, test = generate(3, 200, 0), generate(3, 100, 1)
    det = create("matched-filter", tiny_config("matched-filter")).fit(train.X)
    scores = det.score(test.X)
    test.save(folder / "test.npz")
    write_scores(folder / "scores.npz", det, scores)
    return folder, det, test, scores


def test_scores_round_trip(scored) -> None:  # type: ignore[no-untyped-def]
    folder, det, _, scores = scored
    back, threshold = read_scores(folder / "scores.npz")
    assert threshold == det.threshold_
    for key in ("instance", "point", "channel"):
        np.testing.assert_array_equal(getattr(back, key), getattr(scores, key))
    with np.load(folder / "scores.npz") as f:
        assert str(f["detector"]) == "matched-filter"
        loc = localize(scores.point, scores.channel, det.config.fs)
        np.testing.assert_array_equal(f["time_index"], loc.time_index)
        np.testing.assert_array_equal(f["channel_index"], loc.channel)


def test_evaluate_files_equals_the_metrics(scored) -> None:  # type: ignore[no-untyped-def]
    folder, det, test, scores = scored
    windows, metrics = evaluate_files(folder / "test.npz", folder / "scores.npz")
    assert windows.n == test.n
    assert metrics == evaluate_scores(test.y, test.mask, test.channel, scores, det.threshold_)


def test_errors_are_one_line(scored, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    folder, _, test, _ = scored
    np.savez(tmp_path / "other.npz", instance=np.zeros(3))
    with pytest.raises(RailwatchError, match="lacks point, channel, threshold: is it a scores"):
        read_scores(tmp_path / "other.npz")
    with pytest.raises(RailwatchError, match="no such file"):
        read_scores(tmp_path / "missing.npz")
    generate(3, 50, 2).save(tmp_path / "fewer.npz")
    with pytest.raises(RailwatchError, match="were they computed on"):
        evaluate_files(tmp_path / "fewer.npz", folder / "scores.npz")
