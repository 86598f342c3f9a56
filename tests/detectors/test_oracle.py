"""The oracle (spec/detectors.md, "Reference detectors") and the shared GLR scan statistics."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ndtri
from sklearn.metrics import roc_auc_score

from railwatch.detectors import create
from railwatch.detectors.glr import (
    box_sums,
    covering_max,
    effective_counts,
    families,
    family_max,
    log10_familywise_p,
)
from railwatch.errors import RailwatchError
from railwatch.synthetic import generate


def brute_family_max(g: np.ndarray, lengths: tuple[int, ...]) -> np.ndarray:
    """Loop over every window, channel, sample and covering box: max |sum| / √L."""
    n, t_len, c = g.shape
    out = np.full(g.shape, -np.inf)
    for i in range(n):
        for ch in range(c):
            for t in range(t_len):
                for L in lengths:
                    for s in range(max(0, t - L + 1), min(t, t_len - L) + 1):
                        z = abs(g[i, s:s + L, ch].sum()) / np.sqrt(L)
                        out[i, t, ch] = max(out[i, t, ch], z)
    return out


def test_box_sums_and_covering_max_match_loops() -> None:
    rng = np.random.default_rng(0)
    g = rng.standard_normal((2, 30, 2))
    for L in (1, 5, 6, 20):
        sums = box_sums(g, L)
        assert sums.shape == (2, 30 - L + 1, 2)
        np.testing.assert_allclose(sums[1, 3, 1], g[1, 3:3 + L, 1].sum())
        cov = covering_max(sums, L)
        for t in range(30):
            starts = range(max(0, t - L + 1), min(t, 30 - L) + 1)
            np.testing.assert_allclose(cov[:, t], np.max([sums[:, s] for s in starts], axis=0))


def test_family_max_matches_brute_force() -> None:
    rng = np.random.default_rng(1)
    g = rng.standard_normal((2, 26, 2))
    for fam in families(5, 8):
        got = family_max(g, fam, [np.sqrt(L) for L in fam])
        np.testing.assert_allclose(got, brute_family_max(g, fam))


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


def test_familywise_p_is_monotone_and_continuous_across_branches() -> None:
    z = np.linspace(0.1, 60.0, 5000)
    lp = log10_familywise_p(z, 200.0)
    assert np.isfinite(lp).all() and (lp <= 0).all()
    assert np.all(np.diff(lp) <= 0)  # p saturates at 1 for small z ...
    tail = lp < -0.01
    assert np.all(np.diff(lp[tail]) < 0)  # ... and falls strictly in the tail
    z_switch = -ndtri(0.5e-8)  # where the stable branch (q < 1e-8) takes over: no jump there
    below, above = log10_familywise_p(np.array([z_switch - 1e-9, z_switch + 1e-9]), 200.0)
    assert abs(below - above) < 1e-6
    # single test: the two-sided normal tail; z = 1.96 -> p = 0.05
    np.testing.assert_allclose(log10_familywise_p(np.array([1.959964]), 1.0), np.log10(0.05),
                               atol=1e-5)


def test_effective_counts_spike_family_is_the_window_length() -> None:
    spike, box = effective_counts(200, families(5, 20), n_windows=4000, alpha=0.05, seed=0)
    assert 170 < spike < 230  # independent samples: m = T
    assert spike < box < sum(200 - L + 1 for L in range(5, 21))  # overlapping boxes


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
