"""Progress: log lines when there is no terminal (make run > log), nothing when quiet."""

from __future__ import annotations

import logging

import pytest

from railwatch import progress as P


@pytest.fixture
def clock(monkeypatch):  # type: ignore[no-untyped-def]
    """A hand-driven monotonic clock for the progress module."""
    now = [100.0]
    monkeypatch.setattr(P.time, "monotonic", lambda: now[0])
    return now


def lines(caplog) -> list[str]:  # type: ignore[no-untyped-def]
    return [r.getMessage() for r in caplog.records if r.name == "railwatch.progress"]


def test_a_line_per_update_with_an_estimate_from_timed_work(clock, caplog) -> None:  # type: ignore[no-untyped-def]
    caplog.set_level(logging.INFO)
    with P.Progress(10, "bench", "cells", every_s=0.0, terminal=False) as bar:
        bar.update(4, timed=False)  # reused cells: counted, no line, not in the estimate
        clock[0] += 30
        bar.set_postfix_str("stage1-cnn-ae-seed0 AUC 0.912")
        bar.update(1)
        clock[0] += 30
        bar.update(5)
    assert lines(caplog) == [
        "bench: 5/10 cells (50%), 0:30 elapsed, ~2:30 left; stage1-cnn-ae-seed0 AUC 0.912",
        "bench: 10/10 cells (100%), 1:00 elapsed; stage1-cnn-ae-seed0 AUC 0.912",
    ]


def test_lines_are_throttled_and_the_end_is_always_said(clock, caplog) -> None:  # type: ignore[no-untyped-def]
    caplog.set_level(logging.INFO)
    bar = P.Progress(600, "detect", "s of recording", every_s=10.0, terminal=False)
    for _ in range(60):  # a block of 10 s of recording every second
        clock[0] += 1
        bar.update(10)
    bar.close()
    got = lines(caplog)
    assert len(got) == 7 and got[-1].startswith("detect: 600/600 s of recording (100%)")
    stopped = P.Progress(600, "detect", "s", every_s=1e9, terminal=False)
    stopped.update(60)
    stopped.update(60)
    stopped.close()  # interrupted: the last count is said once more
    assert lines(caplog)[-1].startswith("detect: 120/600 s (20%)")


def test_quiet_shows_nothing(caplog) -> None:  # type: ignore[no-untyped-def]
    caplog.set_level(logging.INFO)
    with P.Progress(3, "bench", "cells", enabled=False, terminal=False) as bar:
        bar.update(3)
    assert lines(caplog) == []
