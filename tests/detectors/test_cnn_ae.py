"""CNN autoencoder: shapes through the bottleneck, odd lengths, the window-relative error, AUC."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from sklearn.metrics import roc_auc_score

from railwatch.detectors import create
from railwatch.detectors.cnn_ae import ConvAutoencoder, window_relative
from railwatch.synthetic import generate


@pytest.mark.parametrize("n_steps", [200, 203, 37, 5])
def test_any_length_round_trips(n_steps: int) -> None:
    model = ConvAutoencoder(n_channels=3, widths=(8, 8, 8, 8), latent=2, kernel=7)
    x = torch.randn(2, n_steps, 3)
    z = model.encoder(torch.nn.functional.pad(x.transpose(1, 2), (0, -n_steps % 16),
                                              mode="replicate"))
    assert z.shape == (2, 2, -(-n_steps // 16))  # (B, latent, ceil(T / 2^L)): the bottleneck
    assert model(x).shape == x.shape


def test_fit_and_score_a_length_not_a_multiple_of_the_stride() -> None:
    train = generate(1, 60, seed=0).X[:, :193]
    det = create("cnn-ae", {"epochs": 1, "widths": (4, 4), "progress": False}).fit(train)
    s = det.score(train[:5])
    assert s.point.shape == (5, 193) and s.channel.shape == (5, 193, 1)
    assert np.isfinite(s.channel).all()


def test_window_relative_divides_by_each_windows_median_per_channel() -> None:
    rng = np.random.default_rng(0)
    e = rng.random((4, 9, 3)) + 0.1
    scale = np.array([1.0, 10.0, 0.01])
    r = window_relative(e * scale)  # a per-channel noise level cancels out
    np.testing.assert_allclose(r, window_relative(e), rtol=1e-6)
    np.testing.assert_allclose(np.median(r, axis=1), 1.0, rtol=1e-6)


@pytest.mark.slow
def test_stage_1_instance_auc() -> None:
    """Default config (measured 0.967)."""
    train, test = generate(1, 2000, seed=0), generate(1, 1000, seed=1)
    det = create("cnn-ae", {"progress": False}).fit(train.X)
    assert roc_auc_score(test.y, det.score(test.X).instance) >= 0.93
