"""MSCRED: signature matrices against a brute-force loop, the 8×8 zero-padding, a minimum AUC."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from sklearn.metrics import roc_auc_score

from railwatch.detectors import create
from railwatch.detectors.mscred import pad_matrices, signature_matrices, step_ends
from railwatch.synthetic import generate


def brute_force(x: np.ndarray, scales: tuple[int, ...], gap: int) -> np.ndarray:
    """M_ij = Σ_{δ<w} x_i(t−δ) x_j(t−δ) / w by explicit loops, left edge reflected."""
    n, t_len, c = x.shape
    ends = step_ends(t_len, gap)
    out = np.zeros((n, len(ends), len(scales), c, c))
    for b in range(n):
        for k, t in enumerate(ends):
            for s, w in enumerate(scales):
                for d in range(w):
                    u = t - d
                    u = -u if u < 0 else u  # reflection: x(−u) = x(u)
                    out[b, k, s] += np.outer(x[b, u], x[b, u])
                out[b, k, s] /= w
    return out


@pytest.mark.parametrize("n_channels, n_steps", [(1, 200), (2, 200), (6, 200), (3, 95)])
def test_signature_matrices_match_brute_force(n_channels: int, n_steps: int) -> None:
    x = np.random.default_rng(n_channels).normal(size=(2, n_steps, n_channels))
    got = signature_matrices(torch.from_numpy(x), (10, 30, 60), 10).numpy()
    want = brute_force(x, (10, 30, 60), 10)
    assert got.shape == (2, -(-n_steps // 10), 3, n_channels, n_channels)
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(got, got.swapaxes(-1, -2))  # symmetric


def test_steps_cover_the_window() -> None:
    assert step_ends(200, 10).tolist() == list(range(9, 200, 10))  # 20 steps, each its 10 samples


@pytest.mark.parametrize("n_channels", [1, 2])
def test_zero_padding_to_8x8(n_channels: int) -> None:
    m = torch.rand(3, 20, 3, n_channels, n_channels) + 0.5
    padded = pad_matrices(m)
    assert padded.shape == (3, 20, 3, 8, 8)
    torch.testing.assert_close(padded[..., :n_channels, :n_channels], m)
    assert (padded[..., n_channels:, :] == 0).all() and (padded[..., :, n_channels:] == 0).all()
    assert (padded[..., :n_channels, :n_channels] != 0).all()


def test_no_padding_from_8_channels() -> None:
    m = torch.rand(2, 4, 3, 9, 9)
    assert pad_matrices(m) is m


def test_channel_scores_use_only_real_channels() -> None:
    train = generate(3, 60, seed=0)
    det = create("mscred", {"progress": False, "epochs": 1, "filters": (2, 4, 4, 8)})
    s = det.fit(train.X).score(train.X[:4])
    assert s.channel.shape == (4, 200, 2) and s.point.shape == (4, 200)
    # each step's score covers its 10 samples
    assert (s.point.reshape(4, 20, 10) == s.point.reshape(4, 20, 10)[:, :, :1]).all()
    assert (s.channel.reshape(4, 20, 10, 2) == s.channel.reshape(4, 20, 10, 2)[:, :, :1]).all()


AUC_FLOOR = 0.77  # measured 0.796 with the default config (seeded, CPU)


@pytest.mark.slow
def test_stage1_auc() -> None:
    train, test = generate(1, 2000, seed=0), generate(1, 1000, seed=1)
    det = create("mscred", {"progress": False}).fit(train.X)
    auc = roc_auc_score(test.y, det.score(test.X).instance)
    assert auc >= AUC_FLOOR, auc

