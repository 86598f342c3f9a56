"""The report's figures: drawn from what they are given, written whole."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from railwatch.recordings.pipeline import Detection, Trace
from railwatch.recordings.stream import Event
from railwatch.report import figures as F
from railwatch.synthetic import stage_examples


def test_stages_figure_draws_one_anomalous_window_per_stage(tmp_path: Path) -> None:
    examples = stage_examples(0)
    assert [int(d.meta["stage"]) for d, _ in examples] == list(range(1, 9))
    assert all(d.y is not None and d.y[i] == 1 for d, i in examples)
    kinds = [int(d.kind[i]) for d, i in examples]  # type: ignore[index]
    assert kinds == [1, 2] * 4  # odd stages a spike, even stages a local deviation
    fig = F.stages_figure(examples, 0)
    titles = [ax.get_title() for ax in fig.axes]
    assert len(titles) == 8 and titles[6].startswith("Stage 7: ")
    path = F.save_figure(fig, tmp_path / "stages.png", dpi=40)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_plot_detection(tmp_path: Path) -> None:
    trace = Trace()
    t = np.arange(0, 60, 0.01)
    trace.add(t, np.abs(np.sin(t)), np.zeros((len(t), 1)), 20.0 * t)
    event = Event(start_s=10.0, end_s=10.2, peak_s=10.1, channel="axle_left", group="axle",
                  score=5.0, threshold=0.9, position_m=202.0)
    det = Detection([event], trace.finish(), 0.9, 60.0, True)
    path = F.plot_detection(det, tmp_path / "run.png", truth=[10.1, 30.0])
    assert path.stat().st_size > 5_000
