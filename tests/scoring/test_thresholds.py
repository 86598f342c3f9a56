"""Threshold rules: the contamination quantile and the Gumbel null of recordings."""

from __future__ import annotations

import numpy as np

from railwatch.scoring.thresholds import ContaminationQuantile, GumbelNull


def test_contamination_quantile_is_the_quantile() -> None:
    scores = np.random.default_rng(0).normal(size=1000)
    assert ContaminationQuantile(0.1).fit(scores) == float(np.quantile(scores, 0.9))
    assert ContaminationQuantile(0.25).describe() == "contamination_quantile(contamination=0.25)"


def test_gumbel_null_holds_when_defects_fill_a_fifth_of_the_windows() -> None:
    """Defects in 10-20 % of the windows (high scores) move the null's threshold a little
    (measured: 0.28 and 0.72 on a null of scale 0.5); the contamination quantile lands among
    the defects (3.0 and 11.3 higher)."""
    rng = np.random.default_rng(1)
    null = rng.gumbel(2.0, 0.5, 5000)
    alone = GumbelNull(0.02).fit(null)
    assert abs(alone - float(np.quantile(null, 0.98))) < 0.1
    for share in (0.1, 0.2):
        scores = null.copy()
        scores[: int(share * len(scores))] = rng.uniform(10, 20, int(share * len(scores)))
        moved = GumbelNull(0.02).fit(scores) - alone
        assert 0 <= moved < 1.0
        assert ContaminationQuantile(0.1).fit(scores) - alone > 4 * moved
    assert GumbelNull(0.02).describe() == "gumbel_null(tail=0.02)"
