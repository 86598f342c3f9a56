"""Anomaly Transformer: the official mathematics, checked against explicit numpy formulas."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from railwatch.detectors import create
from railwatch.detectors.anomaly_transformer import (
    AnomalyAttention,
    AnomalyTransformerConfig,
    AnomalyTransformerNet,
    association_weight,
    minimax_objective,
    official_config,
    point_discrepancy,
)
from railwatch.evaluation.metrics import auc_instance
from railwatch.synthetic import generate


def np_softmax(z: np.ndarray) -> np.ndarray:
    e = np.exp(z - z.max(axis=-1, keepdims=True))
    return e / e.sum(axis=-1, keepdims=True)


def official_kl(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The official my_kl_loss for one head: sum_j p (log(p + 1e-4) - log(q + 1e-4)), (L,)."""
    out = np.zeros(len(p))
    for i in range(len(p)):
        for j in range(p.shape[1]):
            out[i] += p[i, j] * (math.log(p[i, j] + 1e-4) - math.log(q[i, j] + 1e-4))
    return out


def test_attention_prior_and_discrepancy_match_hand_computation() -> None:
    L, D = 4, 4
    rng = np.random.default_rng(3)
    x = rng.normal(size=(L, D))
    weights = {name: (rng.normal(scale=0.5, size=(out, D)), rng.normal(scale=0.1, size=out))
               for name, out in [("query", D), ("key", D), ("value", D), ("sigma", 1), ("out", D)]}
    attn = AnomalyAttention(D, n_heads=1, dropout=0.0)
    with torch.no_grad():
        for name, (w, b) in weights.items():
            getattr(attn, name).weight.copy_(torch.tensor(w))
            getattr(attn, name).bias.copy_(torch.tensor(b))
    with torch.no_grad():
        out, series, prior, sigma = attn(torch.tensor(x[None], dtype=torch.float32))

    def lin(name: str) -> np.ndarray:
        w, b = weights[name]
        return x @ w.T + b

    q, k, v = lin("query"), lin("key"), lin("value")
    series_np = np_softmax(q @ k.T / math.sqrt(D))  # series association
    s_raw = lin("sigma")[:, 0]
    sigma_np = 3.0 ** (1 / (1 + np.exp(-5 * s_raw)) + 1e-5) - 1  # (L,)
    dist = np.abs(np.arange(L)[:, None] - np.arange(L)[None, :])
    gauss = np.exp(-dist**2 / (2 * sigma_np[:, None] ** 2)) / (
        math.sqrt(2 * math.pi) * sigma_np[:, None])
    prior_np = gauss / gauss.sum(axis=1, keepdims=True)  # row-normalised prior
    out_np = (series_np @ v) @ weights["out"][0].T + weights["out"][1]

    assert 0.1 < sigma_np.min() and sigma_np.max() < 2.0  # a prior that is not a delta
    np.testing.assert_allclose(sigma[0, 0].numpy(), sigma_np, rtol=1e-5)
    np.testing.assert_allclose(series[0, 0].numpy(), series_np, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(prior[0, 0].numpy(), prior_np, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(out[0].numpy(), out_np, rtol=1e-4, atol=1e-6)

    # association discrepancy per step: KL(S||P) + KL(P||S) with the 1e-4 guard
    disc_np = official_kl(series_np, prior_np) + official_kl(prior_np, series_np)
    disc = point_discrepancy([series], [prior])
    np.testing.assert_allclose(disc[0].numpy(), disc_np, rtol=1e-4, atol=1e-6)

    # score weight: softmax over steps of -50 * discrepancy
    w_np = np.exp(-50 * disc_np) / np.exp(-50 * disc_np).sum()
    np.testing.assert_allclose(association_weight(disc_np[None], 50.0)[0], w_np, rtol=1e-5)


def test_discrepancy_averages_heads_and_sums_layers() -> None:
    rng = np.random.default_rng(0)
    maps = [torch.softmax(torch.tensor(rng.normal(size=(2, 3, 5, 5)) * 3), dim=-1)
            for _ in range(4)]  # two layers of (B=2, H=3, T=5, T=5) series and priors
    got = point_discrepancy(maps[:2], maps[2:]).numpy()  # (2, 5)
    want = np.zeros((2, 5))
    for layer in range(2):
        s, p = maps[layer].numpy(), maps[2 + layer].numpy()
        for b in range(2):
            want[b] += np.mean([official_kl(s[b, h], p[b, h]) + official_kl(p[b, h], s[b, h])
                                for h in range(3)], axis=0)
    np.testing.assert_allclose(got, want, rtol=1e-6)


def test_minimax_gradient_equals_the_official_two_backward_step() -> None:
    """One backward of minimax_objective = loss1.backward(retain_graph=True); loss2.backward()."""
    cfg = AnomalyTransformerConfig(d_model=8, n_heads=2, e_layers=2, d_ff=8)
    torch.manual_seed(0)
    net = AnomalyTransformerNet(12, 2, cfg).double()
    x = torch.randn(3, 12, 2, dtype=torch.float64)

    def kl(p: torch.Tensor, q: torch.Tensor) -> torch.Tensor:  # official my_kl_loss
        return torch.mean(torch.sum(p * (torch.log(p + 1e-4) - torch.log(q + 1e-4)), -1), 1)

    recon, series, priors, _ = net(x)
    rec = torch.nn.functional.mse_loss(recon, x)
    series_loss = sum(kl(s, p.detach()).mean() + kl(p.detach(), s).mean()
                      for s, p in zip(series, priors, strict=True)) / 2
    prior_loss = sum(kl(p, s.detach()).mean() + kl(s.detach(), p).mean()
                     for s, p in zip(series, priors, strict=True)) / 2
    (rec - 3 * series_loss).backward(retain_graph=True)
    (rec + 3 * prior_loss).backward()
    official = {n: p.grad.clone() for n, p in net.named_parameters()}
    net.zero_grad()

    recon, series, priors, _ = net(x)
    objective, disc = minimax_objective(torch.nn.functional.mse_loss(recon, x), series, priors,
                                        3.0)
    objective.backward()
    np.testing.assert_allclose(disc.item(), series_loss.item(), rtol=1e-12)
    assert any(float(g.abs().max()) > 0 for n, g in official.items() if "sigma" in n)
    for name, p in net.named_parameters():
        torch.testing.assert_close(p.grad, official[name], rtol=1e-9, atol=1e-12, msg=name)


def test_learning_rate_schedule_history_and_extras() -> None:
    train = generate(1, 40, seed=0)
    det = create("anomaly-transformer", {"d_model": 8, "n_heads": 2, "e_layers": 1, "d_ff": 8,
                                         "epochs": 4, "patience": 0, "lr": 1e-3,
                                         "progress": False})
    det.fit(train.X)
    # official adjust_learning_rate: lr * 0.5 ** (epoch - 1), set after each (1-based) epoch
    assert [h["lr"] for h in det.history_] == [1e-3, 1e-3, 5e-4, 2.5e-4]
    assert {"rec", "discrepancy", "loss1", "loss2", "val_rec", "val_loss2"} <= set(det.history_[0])

    assert det.score(train.X[:3]).extras == {}
    s = det.score(train.X[:3], extras=True)
    assert s.extras["series"].shape == s.extras["prior"].shape == (3, 1, 2, 200, 200)
    assert s.extras["sigma"].shape == (3, 1, 2, 200)
    np.testing.assert_allclose(s.extras["prior"].sum(-1), 1.0, rtol=1e-5)
    np.testing.assert_allclose(s.extras["weight"].sum(-1), 1.0, rtol=1e-5)
    # point = softmax weight x MSE over channels; channel = weight x squared error
    np.testing.assert_allclose(s.point, s.channel.mean(axis=2), rtol=1e-5)
    np.testing.assert_array_equal(s.instance, s.point.max(axis=1))


def test_official_sizes_are_available() -> None:
    cfg = official_config()
    assert (cfg.d_model, cfg.n_heads, cfg.e_layers, cfg.d_ff, cfg.k) == (512, 8, 3, 512, 3.0)
    net = AnomalyTransformerNet(100, 38, cfg)
    assert sum(p.numel() for p in net.parameters()) > 4_000_000


@pytest.mark.slow
def test_stage1_auc_and_minimax_dynamics() -> None:
    train, test = generate(1, 2000, seed=0), generate(1, 1000, seed=1)
    det = create("anomaly-transformer", {**SLOW, "progress": False}).fit(train.X)
    first, last = det.history_[0], det.history_[-1]
    assert last["rec"] < first["rec"]  # reconstruction improves
    assert last["discrepancy"] > first["discrepancy"]  # while the series moves away from prior
    assert auc_instance(test.y, det.score(test.X).instance) >= 0.55


# A small model for a CI-sized run (about a minute on 2 cores). Early stopping on loss1: the
# official two-loss rule keeps the first epoch's weights here (see the module docstring).
SLOW = {"d_model": 32, "n_heads": 2, "e_layers": 1, "d_ff": 32, "lr": 1e-2, "epochs": 5,
        "early_stopping": "loss1"}
