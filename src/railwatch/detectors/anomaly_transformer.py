"""Anomaly Transformer (Xu et al., ICLR 2022): association discrepancy, minimax training.

A port of the mathematics of the official code (github.com/thuml/Anomaly-Transformer:
``model/embed.py``, ``model/attn.py``, ``model/AnomalyTransformer.py``, ``solver.py``), written
device-agnostic; ``docs/detectors.md``, "Anomaly Transformer".

Model (paper Section 3.1, Figure 1):

- ``DataEmbedding``: Conv1d token embedding (kernel 3, circular padding, no bias, Kaiming-normal
  init) plus the sinusoidal positional embedding, then dropout.
- ``e_layers`` encoder layers. Anomaly attention (paper Eq. 2) gives two associations per layer
  and head: the *series association* ``S = softmax(QKᵀ/√E)`` and the *prior association*, a
  Gaussian kernel over the distance ``|i − j|`` with a learned, input-dependent scale per step and
  head, ``σ = 3^(sigmoid(5·σ_raw) + 1e−5) − 1`` (so σ ∈ (0, 2] steps),
  ``P_ij = exp(−|i−j|²/(2σ_i²)) / (√(2π) σ_i)``, normalised over ``j``. Then residual + LayerNorm,
  a Conv1d(k=1) feed-forward with GELU, residual + LayerNorm.
- A final LayerNorm and a linear head reconstructing the (normalised) input.

Association discrepancy (paper Eq. 3, ``my_kl_loss`` of the official solver): the symmetric KL
``KL(P‖S) + KL(S‖P)`` with a ``+1e−4`` guard inside each log, summed over the key axis and
averaged over heads, giving one value per query step.

Minimax training (paper Eq. 4-5, ``Solver.train``): ``loss1 = rec − k·series_loss`` with the prior
detached (the series association is pushed away from the prior) and ``loss2 = rec + k·prior_loss``
with the series detached (the prior is pulled towards the series), where ``rec`` is the MSE and both
discrepancy terms are averaged over layers, heads, steps and windows. Both are backpropagated into
one Adam step; ``k = 3``. The official calls ``loss1.backward(retain_graph=True);
loss2.backward()``; here one backward pass of ``2·rec + k·D(R(S), P)``, ``R`` reversing the
gradient, accumulates exactly the same gradient at about half the cost (:func:`minimax_objective`;
the tests compare it with the two-pass form). The learning rate follows the official
``adjust_learning_rate``: after epoch ``e`` (1-based) it is set to ``lr · 0.5^(e−1)``, so epochs 1
and 2 run at ``lr`` and every later epoch at half the previous rate. Early stopping mirrors the
official ``EarlyStopping`` with ``early_stopping="official"``: an epoch counts as an
improvement, and its weights are kept, only when both validation ``loss1`` and ``loss2`` are at or
below their best, with the base's patience (3, the official value). Since the minimax makes the
discrepancy grow, ``loss2 = rec + k·D`` usually rises from the second epoch on, so this rule usually
keeps the first epoch's weights (the official issue #38 reports the same).
The default, ``early_stopping="loss1"``, judges ``loss1`` alone, the official's printed "Vali
Loss": with our short epochs (about 57 steps of 32 windows against thousands in the official
runs) the official rule keeps a barely trained first epoch (stage-1 AUC 0.52, against 0.65 with
``loss1``). The official
code validates on its test loader; here the validation split is carved from the training windows by
the base class, never from test data.

Score (paper Eq. 6, ``Solver.test``): per step,
``softmax over steps of (−temperature · Σ_layers discrepancy)`` × the reconstruction MSE (mean
over channels), temperature 50. The official sums the per-step KL over layers here (while training
averages it), and so does this port. The channel score is the same weight × the per-channel squared
error; point = that weighted MSE (the channel mean, as the paper, not the default max);
instance = max over steps (the default). No point adjustment; the threshold is the base's
training-score quantile.

Sizes: the official model has d_model 512, 8 heads, 3 layers, d_ff 512 (``official_config()``). The
default here is CPU-friendly: d_model 64, 4 heads, 2 layers, d_ff 64, dropout 0, 5 epochs, batch
32, learning rate 1e-3: the official 1e-4 is tuned for epochs of thousands of steps (stride-1
windows over long series, batch 256); an epoch here is ~60 steps of 32 windows, and with the rate
halving every epoch 1e-4 leaves the model barely trained. The window is the benchmark's whole window
(200 steps of a 2-s window at 100 Hz) used as one sequence; the official slides windows of 100 steps
over long series, but this project scores whole 2-s windows, and the model has no length-specific
weights (the positional table and distances are computed for any length).

``score(X, extras=True)`` adds ``series`` and ``prior`` (N, layers, heads, T, T), ``sigma``
(N, layers, heads, T), ``discrepancy`` (N, T, summed over layers, before the temperature) and
``weight`` (N, T, the softmax). The maps are large: series and prior of 1 000 windows at the
default size take 2.6 GB.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn
from torch.nn import functional as F

from railwatch.detectors.api import GLR_SCORING, DetectorConfig, FloatArray, Scores, TrainConfig
from railwatch.detectors.training import TorchDetector
from railwatch.errors import RailwatchError
from railwatch.scoring.reduce import reduce_instance_max

log = logging.getLogger(__name__)

KL_GUARD = 1e-4  # added inside the logs of the discrepancy (official my_kl_loss)
EARLY_STOPPING = ("official", "loss1")
EXP_FLOOR = -87.0  # floor of the prior's exponent: exp(-87) ≈ 1.6e-38 (see gaussian_prior)


@dataclass(frozen=True)
class AnomalyTransformerConfig(TrainConfig):
    d_model: int = 64  # official 512
    n_heads: int = 4  # official 8
    e_layers: int = 2  # official 3
    d_ff: int = 64  # official 512
    dropout: float = 0.0  # official 0.0 (embedding, attention and feed-forward)
    k: float = 3.0  # weight of the association discrepancy in the minimax losses
    temperature: float = 50.0  # of the softmax over steps in the score
    lr: float = 1e-3  # official 1e-4, over ~100x more steps per epoch (see the module docstring)
    epochs: int = 5  # the official default is 10, its scripts use 3 or 10
    early_stopping: str = "loss1"  # "official": val loss1 and loss2 must both improve;
    # "loss1": only loss1 (the official's printed "Vali Loss") must improve
    scoring: str = "paper"  # "paper" (association weight x squared error) or "glr" (the
    # shared GLR scan of the signed reconstruction residual: scoring=glr in docs/detectors.md)


def official_config(**overrides: Any) -> AnomalyTransformerConfig:
    """The sizes of the official model (d_model 512, 8 heads, 3 layers, d_ff 512)."""
    return replace(AnomalyTransformerConfig(d_model=512, n_heads=8, e_layers=3, d_ff=512),
                   **overrides)


# ----------------------------------------------------------------------------- blocks
def sinusoidal_positions(n_steps: int, d_model: int) -> torch.Tensor:
    """The fixed positional table (T, D): sin on even, cos on odd features (Vaswani et al.)."""
    position = torch.arange(n_steps, dtype=torch.float32).unsqueeze(1)  # (T, 1)
    div = torch.exp(torch.arange(0, d_model, 2, dtype=torch.float32)
                    * -(math.log(10000.0) / d_model))  # (D/2,)
    pe = torch.zeros(n_steps, d_model)
    pe[:, 0::2] = torch.sin(position * div)
    pe[:, 1::2] = torch.cos(position * div)
    return pe


class DataEmbedding(nn.Module):
    """(B, T, C) -> (B, T, D): circular Conv1d token embedding + sinusoidal positions."""

    def __init__(self, n_channels: int, d_model: int, n_steps: int, dropout: float) -> None:
        super().__init__()
        self.token = nn.Conv1d(n_channels, d_model, kernel_size=3, padding=1,
                               padding_mode="circular", bias=False)
        nn.init.kaiming_normal_(self.token.weight, mode="fan_in", nonlinearity="leaky_relu")
        self.register_buffer("pe", sinusoidal_positions(n_steps, d_model), persistent=False)
        self.dropout = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        pe: torch.Tensor = self.pe  # type: ignore[assignment]
        if x.shape[1] > len(pe):
            pe = sinusoidal_positions(x.shape[1], pe.shape[1]).to(x.device)
        h = self.token(x.transpose(1, 2)).transpose(1, 2)  # (B, T, D)
        return self.dropout(h + pe[: x.shape[1]])


def transform_sigma(sigma_raw: torch.Tensor) -> torch.Tensor:
    """The learned scale of the prior: ``3^(sigmoid(5σ) + 1e−5) − 1``, in (0, 2] steps."""
    return torch.pow(3.0, torch.sigmoid(5.0 * sigma_raw) + 1e-5) - 1.0


def gaussian_prior(sigma: torch.Tensor) -> torch.Tensor:
    """Prior association (B, H, T, T) from transformed scales ``sigma`` (B, H, T).

    ``P_ij = exp(−|i−j|²/(2σ_i²)) / (√(2π) σ_i)``, normalised over ``j`` (the official solver
    divides by the row sum before every use). The factor ``1/(√(2π) σ_i)`` is constant along a
    row, so it cancels in that normalisation and is not computed (one T×T pass less). The
    exponent is floored at −87 (exp ≈ 1.6e−38, the smallest normal float32): below it ``exp``
    falls into a slow path on CPU (several times slower), and such values are zero for every
    purpose here (each row sums to at least 1, and the discrepancy adds a 1e−4 guard).
    """
    n_steps = sigma.shape[-1]
    steps = torch.arange(n_steps, device=sigma.device, dtype=sigma.dtype)
    distance_sq = (steps[:, None] - steps[None, :]) ** 2  # (T, T)
    exponent = distance_sq * (-0.5 / sigma.unsqueeze(-1) ** 2)  # (B, H, T, T)
    gauss = torch.exp(exponent.clamp_min(EXP_FLOOR))
    return gauss / gauss.sum(dim=-1, keepdim=True)


class AnomalyAttention(nn.Module):
    """Multi-head anomaly attention (B, T, D) -> output (B, T, D), series and prior
    associations (B, H, T, T) and the transformed scales σ (B, H, T)."""

    def __init__(self, d_model: int, n_heads: int, dropout: float) -> None:
        super().__init__()
        if d_model % n_heads:
            raise RailwatchError(f"d_model ({d_model}) must be a multiple of n_heads ({n_heads})")
        self.n_heads = n_heads
        self.query = nn.Linear(d_model, d_model)
        self.key = nn.Linear(d_model, d_model)
        self.value = nn.Linear(d_model, d_model)
        self.sigma = nn.Linear(d_model, n_heads)
        self.out = nn.Linear(d_model, d_model)
        self.dropout = nn.Dropout(dropout)

    def forward(
        self, x: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        B, T, D = x.shape
        H = self.n_heads
        q = self.query(x).view(B, T, H, D // H).transpose(1, 2)  # (B, H, T, E)
        k = self.key(x).view(B, T, H, D // H).transpose(1, 2)
        v = self.value(x).view(B, T, H, D // H).transpose(1, 2)
        sigma = transform_sigma(self.sigma(x).transpose(1, 2))  # (B, H, T)
        prior = gaussian_prior(sigma)  # (B, H, T, T)
        scores = q @ k.transpose(-2, -1) / math.sqrt(D // H)  # (B, H, T, T)
        series = self.dropout(torch.softmax(scores, dim=-1))  # (B, H, T, T)
        y = (series @ v).transpose(1, 2).reshape(B, T, D)  # (B, T, D)
        return self.out(y), series, prior, sigma


class EncoderLayer(nn.Module):
    """Anomaly attention, residual + LayerNorm, Conv1d(k=1) GELU feed-forward, residual +
    LayerNorm."""

    def __init__(self, d_model: int, n_heads: int, d_ff: int, dropout: float) -> None:
        super().__init__()
        self.attention = AnomalyAttention(d_model, n_heads, dropout)
        self.conv1 = nn.Conv1d(d_model, d_ff, kernel_size=1)
        self.conv2 = nn.Conv1d(d_ff, d_model, kernel_size=1)
        self.norm1 = nn.LayerNorm(d_model)
        self.norm2 = nn.LayerNorm(d_model)
        self.dropout = nn.Dropout(dropout)

    def forward(
        self, x: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        a, series, prior, sigma = self.attention(x)
        x = self.norm1(x + self.dropout(a))  # (B, T, D)
        y = self.dropout(F.gelu(self.conv1(x.transpose(1, 2))))  # (B, d_ff, T)
        y = self.dropout(self.conv2(y).transpose(1, 2))  # (B, T, D)
        return self.norm2(x + y), series, prior, sigma


class AnomalyTransformerNet(nn.Module):
    """(B, T, C) -> reconstruction (B, T, C) and, per layer, series, prior (B, H, T, T), σ."""

    def __init__(self, n_steps: int, n_channels: int, cfg: AnomalyTransformerConfig) -> None:
        super().__init__()
        if cfg.d_model % 2:
            raise RailwatchError(f"d_model must be even (sinusoidal positions), got {cfg.d_model}")
        self.embedding = DataEmbedding(n_channels, cfg.d_model, n_steps, cfg.dropout)
        self.layers = nn.ModuleList(
            EncoderLayer(cfg.d_model, cfg.n_heads, cfg.d_ff, cfg.dropout)
            for _ in range(cfg.e_layers)
        )
        self.norm = nn.LayerNorm(cfg.d_model)
        self.head = nn.Linear(cfg.d_model, n_channels)

    def forward(
        self, x: torch.Tensor
    ) -> tuple[torch.Tensor, list[torch.Tensor], list[torch.Tensor], list[torch.Tensor]]:
        h = self.embedding(x)  # (B, T, D)
        series, priors, sigmas = [], [], []
        for layer in self.layers:
            h, s, p, sg = layer(h)
            series.append(s)
            priors.append(p)
            sigmas.append(sg)
        return self.head(self.norm(h)), series, priors, sigmas


# ----------------------------------------------------------------------------- discrepancy
def symmetric_kl(p: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """``KL(p‖q) + KL(q‖p)`` with the 1e−4 log guard, summed over keys, mean over heads.

    (B, H, T, T) × 2 -> (B, T). Equal to the official ``my_kl_loss(p, q) + my_kl_loss(q, p)``:
    ``p(log p − log q) + q(log q − log p) = (p − q)(log p − log q)`` elementwise.
    """
    log_ratio = torch.log(p + KL_GUARD) - torch.log(q + KL_GUARD)
    return ((p - q) * log_ratio).sum(dim=-1).mean(dim=1)


def mean_discrepancy(
    series: Sequence[torch.Tensor], priors: Sequence[torch.Tensor]
) -> torch.Tensor:
    """The training discrepancy (a scalar): mean over windows, steps and heads, then layers.

    The official ``series_loss`` and ``prior_loss`` both have this value; they differ only in
    which association is detached.
    """
    per_layer = [symmetric_kl(s, p).mean() for s, p in zip(series, priors, strict=True)]
    return torch.stack(per_layer).mean()


class _ReverseGradient(torch.autograd.Function):
    """Identity forward; negated gradient backward."""

    @staticmethod
    def forward(ctx: Any, x: torch.Tensor) -> torch.Tensor:
        return x.view_as(x)

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> torch.Tensor:
        return -grad


def minimax_objective(
    rec: torch.Tensor, series: Sequence[torch.Tensor], priors: Sequence[torch.Tensor], k: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """(objective, discrepancy) whose gradient is that of the official minimax step.

    The official step backpropagates ``loss1 = rec − k·D(S, sg(P))`` and then
    ``loss2 = rec + k·D(sg(S), P)`` (``sg``: detached) into the same gradients, so the parameters
    receive ``2∇rec − k·∂D/∂S·∇S + k·∂D/∂P·∇P``. ``2·rec + k·D(R(S), P)``, with ``R`` the identity
    whose backward negates the gradient, has exactly that gradient in one backward pass
    instead of two (and one discrepancy evaluation instead of two).
    """
    reversed_series = [_ReverseGradient.apply(s) for s in series]
    disc = mean_discrepancy(reversed_series, priors)
    return 2 * rec + k * disc, disc


def point_discrepancy(
    series: Sequence[torch.Tensor], priors: Sequence[torch.Tensor]
) -> torch.Tensor:
    """Per-step discrepancy (B, T) summed over layers, as in the official ``Solver.test``."""
    return torch.stack([symmetric_kl(s, p) for s, p in zip(series, priors, strict=True)]).sum(dim=0)


def association_weight(discrepancy: NDArray[Any], temperature: float) -> FloatArray:
    """``softmax over steps of (−temperature · discrepancy)``, (N, T) -> (N, T), rows sum to 1.

    >>> [round(float(v), 4) for v in association_weight(np.array([[0.0, 0.0, 0.1]]), 50.0)[0]]
    [0.4983, 0.4983, 0.0034]
    """
    z = -temperature * np.asarray(discrepancy, dtype=np.float64)
    z -= z.max(axis=1, keepdims=True)
    e = np.exp(z)
    return (e / e.sum(axis=1, keepdims=True)).astype(np.float32)


# ----------------------------------------------------------------------------- detector
class AnomalyTransformer(TorchDetector):
    """Anomaly Transformer detector (see the module docstring).

    After ``fit``, ``history_`` holds one dict per epoch: the learning rate, the training means of
    ``rec``, ``discrepancy``, ``loss1`` and ``loss2``, and the same on the validation split
    (``val_…``). It is a record of the fit and is not saved.
    """

    Config: ClassVar[type[DetectorConfig]] = AnomalyTransformerConfig
    config: AnomalyTransformerConfig  # type: ignore[assignment]
    scoring_fields: ClassVar[tuple[str, ...]] = ("contamination", "scoring")
    scoring_modes: ClassVar[tuple[str, ...]] = ("paper", GLR_SCORING)

    def build(self, n_steps: int, n_channels: int) -> nn.Module:
        return AnomalyTransformerNet(n_steps, n_channels, self.config)

    # -- training --------------------------------------------------------------------------
    def _fit(self, X: FloatArray, context: dict[str, FloatArray]) -> None:
        if self.config.early_stopping not in EARLY_STOPPING:
            raise RailwatchError(f"early_stopping must be one of {', '.join(EARLY_STOPPING)}, "
                                 f"got {self.config.early_stopping!r}")
        self.history_: list[dict[str, float]] = []
        self._sums = np.zeros(3)  # rec · B, discrepancy · B, B of the current epoch
        self._best = (math.inf, math.inf)  # best validation (loss1, loss2)
        self._improvements = 0
        self._maps = False
        super()._fit(X, context)

    def _forward_losses(
        self, xb: torch.Tensor
    ) -> tuple[torch.Tensor, list[torch.Tensor], list[torch.Tensor]]:
        """(rec, series, priors) of a batch: the MSE and the associations of every layer."""
        recon, series, priors, _ = self.model_(xb)
        return F.mse_loss(recon, xb), series, priors

    def loss(self, xb: torch.Tensor) -> torch.Tensor:
        """``loss1 = rec − k·discrepancy``, the official training loss reported per epoch."""
        rec, series, priors = self._forward_losses(xb)
        return rec - self.config.k * mean_discrepancy(series, priors)

    def train_step(self, xb: torch.Tensor) -> float:
        """One minimax step (paper Eq. 5): the official ``loss1.backward(retain_graph=True);
        loss2.backward(); optimizer.step()``, as one backward pass of the equal-gradient
        :func:`minimax_objective`. Returns ``loss1``."""
        self.optimizer_.zero_grad(set_to_none=True)
        rec, series, priors = self._forward_losses(xb)
        objective, disc = minimax_objective(rec, series, priors, self.config.k)
        objective.backward()
        self.optimizer_.step()
        rec_v, disc_v = float(rec.detach()), float(disc.detach())
        self._sums += (rec_v * len(xb), disc_v * len(xb), len(xb))
        return rec_v - self.config.k * disc_v

    def on_epoch_end(self, epoch: int) -> None:
        """Record the epoch's training means; set the next epoch's rate (official
        ``adjust_learning_rate``)."""
        k = self.config.k
        rec, disc = (float(v) for v in self._sums[:2] / max(self._sums[2], 1.0))
        lr = float(self.optimizer_.param_groups[0]["lr"])
        self.history_.append({"epoch": epoch + 1, "lr": lr, "rec": rec, "discrepancy": disc,
                              "loss1": rec - k * disc, "loss2": rec + k * disc})
        self._sums[:] = 0.0
        for group in self.optimizer_.param_groups:  # official: lr · 0.5^(epoch − 1), 1-based
            group["lr"] = self.config.lr * 0.5**epoch

    @torch.no_grad()
    def _evaluate(self, X: FloatArray) -> float:
        """Validation losses into ``history_``; returns the official two-loss stopping signal.

        The base loop stops on one scalar that must decrease to count as an improvement; the
        official ``EarlyStopping`` counts an epoch as an improvement only when validation
        ``loss1`` and ``loss2`` are both at or below their best. So this returns
        ``−(number of improving epochs so far)``, which decreases exactly on those epochs, and the
        base's patience and best-weights restore then follow the official rule
        (``early_stopping="loss1"``: on ``loss1`` alone).
        """
        self.model_.eval()
        k = self.config.k
        total = np.zeros(2)
        for i in range(0, len(X), 256):
            xb = torch.from_numpy(X[i:i + 256]).to(self.device_)
            rec, series, priors = self._forward_losses(xb)
            total += (float(rec) * len(xb), float(mean_discrepancy(series, priors)) * len(xb))
        rec_v, disc_v = (float(v) for v in total / max(len(X), 1))
        loss1, loss2 = rec_v - k * disc_v, rec_v + k * disc_v
        self.history_[-1].update(val_rec=rec_v, val_discrepancy=disc_v, val_loss1=loss1,
                                 val_loss2=loss2)
        both = self.config.early_stopping == "official"
        if loss1 <= self._best[0] and (loss2 <= self._best[1] or not both):
            self._best = (loss1, loss2)
            self._improvements += 1
        log.debug("epoch %d: rec %.5f, discrepancy %.5f (validation)", len(self.history_),
                  rec_v, disc_v)
        return -float(self._improvements)

    # -- scoring ---------------------------------------------------------------------------
    def _score(self, X: FloatArray, context: dict[str, FloatArray], extras: bool) -> Scores:
        self._maps = extras
        try:
            return super()._score(X, context, extras)
        finally:
            self._maps = False

    def raw(self, xb: torch.Tensor) -> dict[str, torch.Tensor]:
        recon, series, priors, sigmas = self.model_(xb)
        out = {"residual": xb - recon,  # (B, T, C)
               "discrepancy": point_discrepancy(series, priors)}  # (B, T)
        if getattr(self, "_maps", False):
            out.update(series=torch.stack(series, dim=1),  # (B, layers, H, T, T)
                       prior=torch.stack(priors, dim=1),
                       sigma=torch.stack(sigmas, dim=1))  # (B, layers, H, T)
        return out

    def scores_from_raw(self, raw: dict[str, NDArray[Any]], extras: bool) -> Scores:
        weight = association_weight(raw["discrepancy"], self.config.temperature)  # (N, T)
        sq_error = raw["residual"] ** 2
        channel = (weight[:, :, None] * sq_error).astype(np.float32)  # (N, T, C)
        point = (weight * sq_error.mean(axis=2)).astype(np.float32)  # (N, T)
        maps: dict[str, NDArray[Any]] = {}
        if extras:
            maps = {k: raw[k] for k in ("series", "prior", "sigma", "discrepancy")}
            maps["weight"] = weight
        return Scores(instance=reduce_instance_max(point), point=point, channel=channel,
                      extras=maps)
