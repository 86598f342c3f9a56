"""LSTM encoder-decoder: Mahalanobis score, reverse-order decoding, free-running inference."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.distance import mahalanobis as scipy_mahalanobis
from sklearn.metrics import roc_auc_score

from railwatch.detectors import create
from railwatch.detectors.lstm_ed import (
    EncoderDecoder,
    LSTMEDConfig,
    LSTMEncoderDecoder,
    fit_gaussian,
    mahalanobis,
    merge_segments,
    split_segments,
)
from railwatch.synthetic import generate


def hand_made_errors() -> np.ndarray:
    rng = np.random.default_rng(0)
    mix = np.array([[1.0, 0.0, 0.0], [0.8, 0.5, 0.0], [0.1, -0.3, 0.2]])
    return np.abs(rng.normal(size=(50, 20, 3)) @ mix).astype(np.float32)  # (N, T, C)


def test_gaussian_and_mahalanobis_match_numpy_and_scipy() -> None:
    e = hand_made_errors()
    mu, cov = fit_gaussian(e, ridge=0.0)
    flat = e.reshape(-1, 3).astype(np.float64)
    np.testing.assert_allclose(mu, flat.mean(axis=0), rtol=1e-10)
    np.testing.assert_allclose(cov, np.cov(flat, rowvar=False), rtol=1e-8)
    precision = np.linalg.inv(cov)
    d2 = mahalanobis(e[:2], mu, precision)
    assert d2.shape == (2, 20)
    expected = [[scipy_mahalanobis(v, mu, precision) ** 2 for v in w] for w in e[:2]]
    np.testing.assert_allclose(d2, expected, rtol=1e-8)


def test_ridge_keeps_collinear_channels_invertible() -> None:
    e = hand_made_errors()[:, :, :1].repeat(2, axis=2)  # two identical channels
    _, cov = fit_gaussian(e, ridge=1e-4)
    assert np.isfinite(np.linalg.inv(cov)).all()
    assert np.diag(cov).min() > np.cov(e.reshape(-1, 2), rowvar=False)[0, 0]


def test_scores_from_raw() -> None:
    e = hand_made_errors()
    det = LSTMEncoderDecoder(LSTMEDConfig(ridge=0.0))
    det.stats_ = {}
    det.fit_statistics({"residual": e})
    s = det.scores_from_raw({"residual": e[:4]}, extras=False)
    mu, cov = e.reshape(-1, 3).mean(axis=0), np.cov(e.reshape(-1, 3), rowvar=False)
    d = e[:4] - mu
    np.testing.assert_allclose(s.point, np.einsum("ntc,cd,ntd->nt", d, np.linalg.inv(cov), d),
                               rtol=1e-4)
    np.testing.assert_allclose(s.channel, d / np.sqrt(np.diag(cov)), rtol=1e-4)
    np.testing.assert_array_equal(s.instance, s.point.max(axis=1))


@torch.no_grad()
def test_decoder_reconstructs_in_reverse_order() -> None:
    """Teacher-forced: x̂_t may depend on the fed x_s only when s > t (decoding runs T -> 1)."""
    torch.manual_seed(0)
    model = EncoderDecoder(n_channels=2, hidden=8)
    x = torch.randn(1, 12, 2)
    state = model.encode(x)  # held fixed: only the decoder's inputs change below
    base = model.decode_teacher_forced(state, x)
    for s in range(12):
        moved = x.clone()
        moved[0, s] += 1.0
        changed = (model.decode_teacher_forced(state, moved) - base).abs().amax(dim=2)[0] > 0
        assert changed.tolist() == [t < s for t in range(12)], s
    # The last step is reconstructed first, from the encoder's final state alone.
    np.testing.assert_allclose(base[0, -1].numpy(), model.head(state[0])[0].numpy(), rtol=1e-6)


@torch.no_grad()
def test_inference_feeds_the_decoder_its_own_previous_output() -> None:
    torch.manual_seed(0)
    model = EncoderDecoder(n_channels=3, hidden=8)
    x = torch.randn(4, 15, 3)
    free = model(x, teacher_forcing=False)
    state = model.encode(x)
    # Explicit loop with an LSTMCell holding the decoder's weights, fed x̂_T, x̂_{T-1}, ...
    cell = torch.nn.LSTMCell(3, 8)
    for name in ("weight_ih", "weight_hh", "bias_ih", "bias_hh"):
        getattr(cell, name).copy_(getattr(model.decoder, f"{name}_l0"))
    h, c = state
    outputs = [model.head(h)]
    for _ in range(14):
        h, c = cell(outputs[-1], (h, c))
        outputs.append(model.head(h))
    np.testing.assert_allclose(free.numpy(), torch.stack(outputs, 1).flip(1).numpy(), atol=1e-5)
    # Teacher forcing on its own outputs is the same computation; on the true x it is not.
    np.testing.assert_allclose(model.decode_teacher_forced(state, free).numpy(), free.numpy(),
                               atol=1e-5)
    assert not torch.allclose(model(x, teacher_forcing=True), free, atol=1e-3)


@pytest.mark.parametrize("length", [0, 5, 7, 12, 40])
def test_segments_are_consecutive_and_merge_back(length: int) -> None:
    x = torch.arange(2 * 12 * 3, dtype=torch.float32).reshape(2, 12, 3)
    segments = split_segments(x, length)
    if 0 < length < 12:
        assert segments.shape == (2 * -(-12 // length), length, 3)
        second = x[0, length:2 * length].numpy()  # window 0's second segment (maybe padded)
        np.testing.assert_array_equal(segments[1, :len(second)].numpy(), second)
    np.testing.assert_array_equal(merge_segments(segments, 2, 12).numpy(), x.numpy())


@pytest.mark.slow
def test_stage_1_instance_auc() -> None:
    """Half the training windows and 8 epochs to stay under a minute (measured 0.81; the default
    config on 2,000 windows reaches 0.91)."""
    train, test = generate(1, 1000, seed=0), generate(1, 1000, seed=1)
    det = create("lstm-ed", {"progress": False, "epochs": 8}).fit(train.X)
    assert roc_auc_score(test.y, det.score(test.X).instance) >= 0.78
