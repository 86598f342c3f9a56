"""The oracle: the calibrated GLR of the true residual, the ceiling of every stage."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.metrics import roc_auc_score

from railwatch.detectors import create
from railwatch.errors import RailwatchError
from railwatch.scoring.glr import log10_familywise_p
from railwatch.synthetic import generate
from support import brute_family_max


def test_oracle_scores_are_the_calibrated_brute_force_glr() -> None:
    train, test = generate(1, 20, seed=0, components=True), generate(1, 6, seed=1, components=True)
    det = create("oracle", {"progress": False, "null_windows": 500})
    det.fit(train.X, {"nuisance": train.nuisance, "noise_std": train.noise_std})
    s = det.score(test.X, {"nuisance": test.nuisance, "noise_std": test.noise_std})
    r = (test.X.astype(np.float64) - test.nuisance) / test.noise_std
    m_spike, m_box = det.stats_["null_counts"]
    expect = np.maximum(-log10_familywise_p(brute_family_max(r, (1,)), m_spike),
                        -log10_familywise_p(brute_family_max(r, tuple(range(5, 21))), m_box))
    np.testing.assert_allclose(s.channel, expect, rtol=1e-5)
    np.testing.assert_array_equal(s.instance, s.channel.max(axis=(1, 2)))


def test_oracle_localises_inside_an_injected_box_on_any_length() -> None:
    train = generate(1, 20, seed=0, components=True)
    det = create("oracle", {"progress": False, "null_windows": 500})
    det.fit(train.X, {"nuisance": train.nuisance, "noise_std": train.noise_std})
    normal = np.flatnonzero(train.y == 0)[:4]
    X, nuis, std = (a[normal, :120].copy() for a in (train.X, train.nuisance, train.noise_std))
    X[:, 40:52, 0] += 3.0 * std[:, 40:52, 0]  # a 12-sample box of 3 noise stds: z ≈ 10
    loc = det.localize(X, {"nuisance": nuis, "noise_std": std})
    assert ((loc.time_index >= 40) & (loc.time_index < 52)).all()
    assert (loc.channel == 0).all()


def test_oracle_without_components_raises() -> None:
    train = generate(1, 10, seed=0, components=True)
    with pytest.raises(RailwatchError, match="needs nuisance, noise_std"):
        create("oracle").fit(train.X)
    with pytest.raises(RailwatchError, match="noise_std must be positive"):
        create("oracle").fit(train.X, {"nuisance": train.nuisance,
                                       "noise_std": np.zeros_like(train.noise_std)})


@pytest.mark.slow
def test_oracle_is_the_stage_1_ceiling() -> None:
    train, test = generate(1, 2000, seed=0, components=True), generate(1, 1000, seed=1,
                                                                      components=True)
    det = create("oracle", {"progress": False})
    det.fit(train.X, {"nuisance": train.nuisance, "noise_std": train.noise_std})
    s = det.score(test.X, {"nuisance": test.nuisance, "noise_std": test.noise_std})
    assert roc_auc_score(test.y, s.instance) >= 0.99  # measured 0.998
