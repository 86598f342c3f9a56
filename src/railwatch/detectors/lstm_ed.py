"""LSTM encoder-decoder, "EncDec-AD" (Malhotra et al. 2016).

Method (``docs/detectors.md``, "LSTM encoder-decoder"; the paper's section 2):

- An encoder LSTM reads the window x_1 .. x_T; its final state (h_T, c_T) initialises the decoder.
- The decoder reconstructs the window in **reverse order**: x̂_T = W h_T^D + b from the initial
  state, then for i = T .. 2 the decoder LSTM takes an input to move from state i to state i − 1
  and predicts x̂_{i−1} = W h_{i−1}^D + b. The input is the true x_i during training (teacher
  forcing) and the decoder's own previous output x̂_i at inference.
- Error vector per step e_t = |x_t − x̂_t| (C values). A Gaussian N(μ, Σ) (full C×C covariance,
  small ridge) is fitted to the error vectors of the validation split; point score = the squared
  Mahalanobis distance (e_t − μ)ᵀ Σ⁻¹ (e_t − μ); channel score = (e_t,c − μ_c) / √Σ_cc, the
  per-channel standardised error; instance = max over time of point (the spec's default).

Sequence length: the paper cuts a series into windows of L steps (its L ranges from 30 to 500 by
dataset). Here each benchmark window is cut into consecutive segments of ``segment`` = L steps,
each encoded and decoded on its own, and the errors are stitched back to (T, C). Free-running
decoding is what limits L: on the benchmark's 1-15 Hz vibration a decoder fed its own output keeps
the phase for a few dozen steps and then drifts to the signal's mean, so over the whole
200-step window (L = T) the reconstruction error is the signal itself and the instance ROC-AUC at
stage 1 is about 0.7; with L = 40 it is about 0.91 (L = 20 or 25: 0.88).

Speed: training runs both LSTMs as fused sequence kernels (teacher forcing makes every decoder
input known in advance). Inference must step the decoder, because each input is the previous
output; since that input is a linear function of the state, x̂_i = W h_i + b, it is folded into the
recurrence: W_ih x̂_i + W_hh h_i = (W_ih W + W_hh) h_i + W_ih b, one matrix product per step.
This is the same computation as feeding x̂_i back (a test checks it against the explicit loop).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from railwatch.detectors.api import GLR_SCORING, DetectorConfig, Scores, TrainConfig
from railwatch.detectors.training import TorchDetector
from railwatch.scoring.reduce import reduce_instance_max


@dataclass(frozen=True)
class LSTMEDConfig(TrainConfig):
    hidden: int = 64  # LSTM state size of the encoder and of the decoder
    segment: int = 40  # the paper's sequence length L: windows are cut into L-step segments (0: T)
    ridge: float = 1e-4  # added to Σ's diagonal, relative to its mean variance
    epochs: int = 20
    lr: float = 3e-3
    scoring: str = "paper"  # "paper" (the score above) or "glr" (the shared GLR scan of the
    # signed residual: scoring=glr in docs/detectors.md)


class EncoderDecoder(nn.Module):
    """Encoder LSTM, decoder LSTM and a linear head, all with ``hidden`` units."""

    def __init__(self, n_channels: int, hidden: int) -> None:
        super().__init__()
        self.encoder = nn.LSTM(n_channels, hidden, batch_first=True)
        self.decoder = nn.LSTM(n_channels, hidden, batch_first=True)
        self.head = nn.Linear(hidden, n_channels)

    def encode(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Final encoder state (h_T, c_T), each (B, H), of windows x (B, T, C)."""
        _, (h, c) = self.encoder(x)
        return h[0], c[0]

    def decode_teacher_forced(
        self, state: tuple[torch.Tensor, torch.Tensor], x: torch.Tensor
    ) -> torch.Tensor:
        """Reconstruction (B, T, C) in time order, the decoder fed the true x_T .. x_2."""
        h0, c0 = state
        inputs = x.flip(1)[:, :-1]  # (B, T − 1, C): x_T, x_{T−1}, .., x_2
        out, _ = self.decoder(inputs, (h0[None], c0[None]))  # states h_{T−1} .. h_1
        states = torch.cat([h0[:, None], out], dim=1)  # (B, T, H): h_T .. h_1
        return self.head(states).flip(1)  # x̂_T .. x̂_1, flipped back to x̂_1 .. x̂_T

    def decode_free_running(
        self, state: tuple[torch.Tensor, torch.Tensor], n_steps: int
    ) -> torch.Tensor:
        """Reconstruction (B, T, C) in time order, the decoder fed its own previous output."""
        h, c = state
        p = dict(self.decoder.named_parameters())
        w_ih, w_hh = p["weight_ih_l0"], p["weight_hh_l0"]  # (4H, C), (4H, H)
        # Input x̂_i = W h_i + b folded into the recurrence (module docstring).
        w = (w_hh + w_ih @ self.head.weight).T  # (H, 4H)
        bias = p["bias_ih_l0"] + p["bias_hh_l0"] + w_ih @ self.head.bias  # (4H,)
        states = [h]
        for _ in range(n_steps - 1):
            i, f, g, o = torch.addmm(bias, h, w).chunk(4, dim=1)  # PyTorch's gate order
            c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
            h = torch.sigmoid(o) * torch.tanh(c)
            states.append(h)
        return self.head(torch.stack(states, dim=1)).flip(1)  # (B, T, C)

    def forward(self, x: torch.Tensor, teacher_forcing: bool) -> torch.Tensor:
        state = self.encode(x)
        if teacher_forcing:
            return self.decode_teacher_forced(state, x)
        return self.decode_free_running(state, x.shape[1])


def split_segments(x: torch.Tensor, length: int) -> torch.Tensor:
    """Windows (B, T, C) cut into consecutive segments (B · ceil(T / L), L, C).

    The last segment is padded by replicating the final step when L does not divide T;
    ``length`` 0 (or ≥ T) keeps whole windows.
    """
    n_windows, n_steps, n_channels = x.shape
    if length <= 0 or length >= n_steps:
        return x
    pad = -n_steps % length
    if pad:
        x = torch.cat([x, x[:, -1:].expand(n_windows, pad, n_channels)], dim=1)
    return x.reshape(-1, length, n_channels)


def merge_segments(x: torch.Tensor, n_windows: int, n_steps: int) -> torch.Tensor:
    """Inverse of :func:`split_segments`: (B · S, L, C) -> (B, T, C), padding cropped."""
    return x.reshape(n_windows, -1, x.shape[2])[:, :n_steps]


def fit_gaussian(errors: NDArray[Any], ridge: float) -> tuple[NDArray[Any], NDArray[Any]]:
    """Mean (C,) and covariance (C, C) of error vectors (N, T, C), pooled over windows and steps.

    The ridge, relative to the mean variance, keeps Σ invertible when channels are collinear.
    """
    e = errors.reshape(-1, errors.shape[-1]).astype(np.float64)
    mu = e.mean(axis=0)
    cov = np.atleast_2d(np.cov(e, rowvar=False))
    cov += np.eye(len(mu)) * (ridge * float(np.trace(cov)) / len(mu) + 1e-12)
    return mu, cov


def mahalanobis(errors: NDArray[Any], mu: NDArray[Any], precision: NDArray[Any]) -> NDArray[Any]:
    """Squared Mahalanobis distance (e − μ)ᵀ Σ⁻¹ (e − μ) of error vectors (..., C) -> (...)."""
    d = errors.astype(np.float64) - mu
    return np.einsum("...c,cd,...d->...", d, precision, d)


class LSTMEncoderDecoder(TorchDetector):
    Config: ClassVar[type[DetectorConfig]] = LSTMEDConfig
    config: LSTMEDConfig  # type: ignore[assignment]
    scoring_fields: ClassVar[tuple[str, ...]] = ("contamination", "scoring")
    scoring_modes: ClassVar[tuple[str, ...]] = ("paper", GLR_SCORING)

    def build(self, n_steps: int, n_channels: int) -> nn.Module:
        return EncoderDecoder(n_channels, self.config.hidden)

    def loss(self, xb: torch.Tensor) -> torch.Tensor:
        model: EncoderDecoder = self.model_  # type: ignore[assignment]
        xs = split_segments(xb, self.config.segment)  # (B · T / L, L, C)
        return nn.functional.mse_loss(model(xs, teacher_forcing=True), xs)

    def raw(self, xb: torch.Tensor) -> dict[str, torch.Tensor]:
        xs = split_segments(xb, self.config.segment)
        rec = merge_segments(self.model_(xs, teacher_forcing=False), xb.shape[0], xb.shape[1])
        return {"residual": xb - rec}  # (B, T, C)

    def fit_statistics(self, raw: dict[str, NDArray[Any]]) -> None:
        mu, cov = fit_gaussian(np.abs(raw["residual"]), self.config.ridge)
        self.stats_["error_mean"] = mu
        self.stats_["error_precision"] = np.linalg.inv(cov)
        self.stats_["error_std"] = np.sqrt(np.diag(cov))

    def scores_from_raw(self, raw: dict[str, NDArray[Any]], extras: bool) -> Scores:
        e = np.abs(raw["residual"])
        mu = self.stats_["error_mean"]
        point = mahalanobis(e, mu, self.stats_["error_precision"]).astype(np.float32)
        channel = ((e - mu) / self.stats_["error_std"]).astype(np.float32)
        return Scores(instance=reduce_instance_max(point), point=point, channel=channel)
