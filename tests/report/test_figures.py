"""The report's figures: drawn from what they are given, written whole."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from railwatch.detection.pipeline import Detection, Trace
from railwatch.detection.stream import Event
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


def test_track_map_figure_draws_the_fused_evidence_and_the_votes(tmp_path: Path) -> None:
    from railwatch import trackmap as tm
    from railwatch.trackmap import fusion

    rng = np.random.default_rng(0)
    xs = [np.arange(0.0, 2000.0, 0.25) for _ in range(3)]
    scores = [rng.exponential(size=len(x)) + 30.0 * (np.abs(x - 700.0) < 0.5) for x in xs]
    fused = fusion.fuse(xs, scores)
    loc = tm.Location(rank=1, position_m=700.0, start_m=699.0, end_m=701.0, evidence=9.0,
                      false_per_km=0.01, passes_seen=3, passes_covered=3, share=1.0,
                      confidence=0.4, median_score=30.0, channel="axle_1", group="axle",
                      kind_guess="spike-like", first_seen="a", last_seen="c")
    passes = [tm.PassEvents(name=n, position=np.array([700.0]), score=np.array([30.0]),
                            duration_s=np.array([0.1]), channel=["axle_1"], group=["axle"],
                            covered=(0.0, 2000.0)) for n in "abc"]
    truth = np.array([[700.0, 700.0]])
    for kwargs in ({"fused": fused, "level": fused.level(0.1)}, {}):
        fig = F.track_map_figure([loc], passes, [loc], truth, **kwargs)
        path = F.save_figure(fig, tmp_path / f"map{len(kwargs)}.png")
        assert path.stat().st_size > 10_000
        assert "1 reported places" in fig.axes[0].get_title()
