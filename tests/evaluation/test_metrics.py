"""Metrics against scikit-learn and brute-force references."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.metrics import roc_auc_score

from railwatch.evaluation import metrics as M


def test_paper7_on_a_hand_made_example() -> None:
    # 200 windows, 20 anomalous. Scores: anomalies ranked 1-4 and 31-46, normals elsewhere.
    n = 200
    y = np.zeros(n, dtype=int)
    rank_of_anomaly = list(range(4)) + list(range(30, 46))
    scores = np.empty(n)
    scores[:] = np.arange(n)[::-1]  # window i has rank i (rank 0 = highest score)
    y[rank_of_anomaly] = 1
    # top 0.5 % = 1 window: 1 TP; 1 % = 2: 2 TP; 1.5 % = 3: 3 TP; 2 % = 4: 4 TP;
    # 10 % = 20: 4 TP, 16 FP; 20 % = 40: 4 + 10 TP, 26 FP; 30 % = 60: 20 TP, 40 FP.
    fpr, tpr = M.paper7_roc(y, scores)
    want = [(0, 0), (0, 1 / 20), (0, 2 / 20), (0, 3 / 20), (0, 4 / 20), (16 / 180, 4 / 20),
            (26 / 180, 14 / 20), (40 / 180, 20 / 20), (1, 1)]
    np.testing.assert_allclose(np.c_[fpr, tpr], want)
    area = sum((b[0] - a[0]) * (a[1] + b[1]) / 2 for a, b in zip(want, want[1:], strict=False))
    assert M.auc_paper7(y, scores) == pytest.approx(area)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(20, 300))
def test_instance_metrics_agree_with_sklearn(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    y = (rng.random(n) < 0.2).astype(int)
    y[:2] = [0, 1]
    s = rng.normal(size=n) + y * rng.random()
    assert M.auc_instance(y, s) == pytest.approx(roc_auc_score(y, s))
    # A perfect ranking has paper7 AUC 1 and AP 1; a random one is far from 1.
    assert M.auc_paper7(y, y + 0.0) == pytest.approx(1.0)
    assert M.ap_instance(y, y + 0.0) == pytest.approx(1.0)
    assert 0.0 <= M.auc_paper7(y, s) <= 1.0


def test_point_auc_and_localisation_against_brute_force() -> None:
    rng = np.random.default_rng(0)
    n, t, c = 30, 50, 3
    mask = np.zeros((n, t, c), bool)
    channel = np.full(n, -1)
    for i in range(0, n, 3):
        start, length, ch = rng.integers(0, 40), rng.integers(1, 10), rng.integers(0, c)
        mask[i, start:start + length, ch] = True
        channel[i] = ch
    point = rng.random((n, t)) + mask.any(axis=2) * 0.5
    labels = [mask[i, j].any() for i in range(n) for j in range(t)]
    assert M.auc_point(mask, point) == pytest.approx(roc_auc_score(labels, point.ravel()))
    time_index = rng.integers(0, t, n)
    hits = []
    for i in range(n):
        steps = np.flatnonzero(mask[i].any(axis=1))
        if steps.size:
            hits.append(steps[0] - 2 <= time_index[i] <= steps[-1] + 2)
    assert M.loc_time(mask, time_index) == pytest.approx(np.mean(hits))
    guess = rng.integers(0, c, n)
    assert M.loc_channel(channel, guess, c) == pytest.approx(
        np.mean([guess[i] == channel[i] for i in range(n) if channel[i] >= 0]))
    assert math.isnan(M.loc_channel(channel, guess, 1))


def test_single_class_gives_nan_not_an_exception() -> None:
    assert math.isnan(M.auc_instance(np.zeros(5), np.arange(5.0)))
    assert M.f1_fitted(np.array([0, 1, 1]), np.array([0, 1, 0])) == pytest.approx(2 / 3)
