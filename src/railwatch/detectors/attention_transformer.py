"""Attention-Focused Transformer (the paper's model): input attention -> self-attention encoder ->
MLP decoder, trained only by reconstruction, scored primarily by how its attention deviates.

Architecture (``docs/detectors.md``, "Attention-Focused Transformer"; the paper's "Proposed Model"):

- **Channel-independent tokens.** Every channel's series is its own sequence through one shared
  network (batch B·C), so every channel has its own attention maps and its own attention score:
  the channel score (N, T, C) is native, and localisation to a channel comes from the attention
  itself, not from a reconstruction error.
- **Input attention.** A Conv1d embeds each sample with its neighbourhood (kernel ``kernel``); a
  learned temporal saliency ``a_t = T · softmax_t(w · e_t)`` (mean 1 over the window)
  re-weights the embedded samples. The weights ``a`` are an output (``extras["input_attention"]``).
- **Patch tokens.** A strided Conv1d merges ``patch`` consecutive weighted samples into one token
  (T = 200, patch 8 -> 25 tokens), plus sinusoidal positions. This is what makes the model fast:
  attention costs L² = 625 per head instead of 40 000 at one token per sample.
- **Encoder.** ``n_layers`` post-norm blocks of multi-head self-attention (written out by hand, so
  that every softmax row can be read) and a GELU feed-forward layer.
- **Decoder.** An MLP per token back to its ``patch`` samples: every time step is reconstructed.

Training is MSE reconstruction only, with Gaussian corruption of the input (a denoising
objective, as in the CNN autoencoder): to undo the corruption the encoder must pool evidence from
the other tokens of the window, so attention learns the window's structure (for a sinusoid, tokens
at the same phase), and the decoder learns the smooth signal rather than the identity.

Scores (``scoring``):

- ``attention`` (the paper's contribution). Per layer, head and token, three features of the
  attention maps: the attention *mass a token receives* (column sum of the map), the *entropy of
  its own row* and its *self-weight* (the diagonal). A one-sample spike or a 5-20-sample offset
  gives its token a key and query unlike any the window's other tokens produce, so the rest of the
  window attends to it abnormally (mass) and its own row becomes atypically sharp or flat
  (entropy, self-weight). Each feature is taken relative to its window's median over tokens (the
  window's own typical attention; frequency, amplitude and noise level vary per window) and
  standardised by robust statistics (median, MAD) of the validation split per channel, layer and
  head. The input attention gives a fourth, per-sample deviation: log ``a_t`` relative to the
  window median, standardised the same way. The sample score is the root mean square of two
  equally weighted parts: the mean squared encoder z-score of the sample's token, and the squared
  input-attention z-score of the sample (the spike detector: a spike is diluted in its 8-sample
  token but not in the per-sample saliency; weighting it as one feature among 13 cost ~0.02 AUC).
  Stage 1 (the quick preset's data, 8 epochs): instance ROC-AUC 0.897 attention, 0.933
  reconstruction, 0.906 combined with the default input scale (each window divided by its own
  std); 0.927 / 0.918 / 0.943 with ``input_scale="training"`` (see ``docs/detectors.md``, "The
  attention model's input scale"). The attention score varies with the training seed.
- ``reconstruction``: the logarithm of the squared reconstruction error per sample and channel
  divided by its window median (a scale-free ratio, robust to the per-window noise level),
  standardised per channel by validation statistics (median, MAD).
- ``combined``: the mean of the two standardised scores.
- ``glr``: the shared GLR scoring of the signed reconstruction residual (not the paper's; the
  same for every reconstruction model: ``TorchDetector.glr_scores``).

In every mode point = max over channels, instance = max over time (the spec's defaults). Scores
are shifted to have validation median 0 and scaled by the validation MAD, so modes are comparable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn
from torch.nn import functional as F

from railwatch.detectors.api import GLR_SCORING, DetectorConfig, FloatArray, Scores, TrainConfig
from railwatch.detectors.training import TorchDetector
from railwatch.errors import RailwatchError
from railwatch.scoring.reduce import reduce_instance_max, reduce_point_max
from railwatch.scoring.residual import MAD_TO_STD

SCORING_MODES = ("attention", "reconstruction", "combined", GLR_SCORING)
INPUT_SCALES = ("window", "training")


# ----------------------------------------------------------------------------- blocks
class InputAttention(nn.Module):
    """Learned temporal saliency over the embedded samples (B, d, T): weights (B, T) with mean 1."""

    def __init__(self, d_embed: int) -> None:
        super().__init__()
        self.score = nn.Conv1d(d_embed, 1, 1, bias=False)  # w · e_t at every step

    def forward(self, e: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        n_steps = e.shape[2]
        logits = self.score(e).squeeze(1)  # (B, T): linear, so a large sample is not squashed
        a = n_steps * F.softmax(logits, dim=-1)  # (B, T), mean 1: a neutral weight is 1
        return e * a.unsqueeze(1), a  # (B, d, T), (B, T)


class SelfAttention(nn.Module):
    """Multi-head self-attention with the softmax written out, so the maps can be returned."""

    def __init__(self, d_model: int, n_heads: int, shared_qk: bool = False) -> None:
        super().__init__()
        self.shared_qk = shared_qk
        if d_model % n_heads:
            raise RailwatchError(
                f"d_model {d_model} is not divisible by n_heads {n_heads}: choose sizes that divide"
            )
        self.n_heads = n_heads
        self.qkv = nn.Linear(d_model, 3 * d_model)
        self.out = nn.Linear(d_model, d_model)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        B, L, D = x.shape
        q, k, v = self.qkv(x).split(D, dim=2)  # each (B, L, D)
        if self.shared_qk:
            q = k
        q = q.view(B, L, self.n_heads, D // self.n_heads).transpose(1, 2)  # (B, H, L, hd)
        k = k.view(B, L, self.n_heads, D // self.n_heads).transpose(1, 2)  # (B, H, L, hd)
        v = v.view(B, L, self.n_heads, D // self.n_heads).transpose(1, 2)  # (B, H, L, hd)
        att = (q @ k.transpose(-2, -1)) * (1.0 / math.sqrt(k.shape[-1]))  # (B, H, L, L)
        att = F.softmax(att, dim=-1)  # row i: where token i looks; rows sum to 1
        y = att @ v  # (B, H, L, hd)
        y = y.transpose(1, 2).reshape(B, L, D)  # (B, L, D)
        return self.out(y), att


class MLP(nn.Module):
    def __init__(self, d_in: int, d_hidden: int, d_out: int) -> None:
        super().__init__()
        self.fc = nn.Linear(d_in, d_hidden)
        self.proj = nn.Linear(d_hidden, d_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(F.gelu(self.fc(x)))


class Block(nn.Module):
    """Post-norm transformer block (Vaswani et al. 2017): ln(x + attn(x)), then ln(x + mlp(x)).

    Post-norm, not nanoGPT's pre-norm: the first layer's attention then sees the token embeddings
    with their magnitudes. A pre-norm LayerNorm rescales every token to unit size before the
    queries and keys, and a 3-unit spike in a patch becomes as small as the noise around it.
    """

    def __init__(self, d_model: int, n_heads: int, d_ff: int, shared_qk: bool = False) -> None:
        super().__init__()
        self.attn = SelfAttention(d_model, n_heads, shared_qk)
        self.ln_1 = nn.LayerNorm(d_model)
        self.mlp = MLP(d_model, d_ff, d_model)
        self.ln_2 = nn.LayerNorm(d_model)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        a, att = self.attn(x)
        x = self.ln_1(x + a)
        x = self.ln_2(x + self.mlp(x))
        return x, att  # (B, L, D), (B, H, L, L)


def sinusoidal_positions(n_tokens: int, d_model: int) -> torch.Tensor:
    """The fixed sinusoidal position code (L, D) of Vaswani et al. 2017."""
    pos = torch.arange(n_tokens, dtype=torch.float32).unsqueeze(1)  # (L, 1)
    div = torch.exp(torch.arange(0, d_model, 2, dtype=torch.float32) * (-math.log(1e4) / d_model))
    pe = torch.zeros(n_tokens, d_model)
    pe[:, 0::2] = torch.sin(pos * div)
    pe[:, 1::2] = torch.cos(pos * div[: d_model // 2])
    return pe


# ----------------------------------------------------------------------------- config
@dataclass(frozen=True)
class AFTConfig(TrainConfig):
    scoring: str = "attention"  # "attention" (the paper's contribution), "reconstruction",
    # or "combined"
    d_model: int = 32
    n_heads: int = 2
    n_layers: int = 2
    d_ff: int = 64  # hidden width of the feed-forward layers and of the decoder MLP
    d_embed: int = 32  # width of the per-sample embedding that the input attention weighs
    patch: int = 8  # samples per token
    kernel: int = 7  # receptive field of the sample embedding (samples)
    train_noise: float = 0.3  # std of the Gaussian corruption of training inputs (normalised units)
    shared_qk: bool = True  # queries = keys: attention row i is a similarity of token i to the rest
    input_scale: str = "window"  # "window": each window and channel divided by its own std
    # before the network (and multiplied back after); "training": only the per-channel
    # standardisation from training statistics, so that a window's level reaches the network
    # (docs/detectors.md, "The attention model's input scale", has the trade-off measured)
    epochs: int = 20
    lr: float = 2e-3
    patience: int = 4


# ----------------------------------------------------------------------------- model
class AttentionFocusedNet(nn.Module):
    """(B, T, C) -> reconstruction (B, T, C), input attention (B, T, C), maps per layer.

    Channels are encoded independently by the same weights: the batch is B·C sequences of one
    channel each.
    """

    def __init__(self, n_steps: int, cfg: AFTConfig) -> None:
        super().__init__()
        self.patch = cfg.patch
        self.window_scale = cfg.input_scale == "window"
        self.n_tokens = -(-n_steps // cfg.patch)
        self.embed = nn.Conv1d(1, cfg.d_embed, cfg.kernel, padding=cfg.kernel // 2)
        self.input_attention = InputAttention(cfg.d_embed)
        self.to_tokens = nn.Conv1d(cfg.d_embed, cfg.d_model, cfg.patch, stride=cfg.patch)
        self.register_buffer("pos", sinusoidal_positions(self.n_tokens, cfg.d_model),
                             persistent=False)
        self.blocks = nn.ModuleList(
            [Block(cfg.d_model, cfg.n_heads, cfg.d_ff, cfg.shared_qk) for _ in range(cfg.n_layers)])
        self.decoder = MLP(cfg.d_model, cfg.d_ff, cfg.patch)

    def forward(
        self, x: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, list[torch.Tensor]]:
        B, T, C = x.shape
        s = x.permute(0, 2, 1).reshape(B * C, 1, T)  # (B·C, 1, T): one sequence per channel
        if self.window_scale:  # amplitude drawn per window: make every sequence unit size
            scale = s.std(dim=2, keepdim=True) + 1e-3  # (B·C, 1, 1): per window and channel
        else:  # the training statistics' standardisation only: a louder window stays louder
            scale = torch.ones_like(s[:, :, :1])
        s = s / scale
        pad = self.n_tokens * self.patch - T
        if pad:  # reflect (replicate when T is too short) up to a whole number of patches
            s = F.pad(s, (0, pad), mode="reflect" if pad < T else "replicate")
        e = self.embed(s)  # (B·C, d, T'): each sample with its neighbourhood
        e, a = self.input_attention(e)  # (B·C, d, T'), (B·C, T')
        h = self.to_tokens(e).transpose(1, 2)  # (B·C, L, D)
        h = h + self.pos
        maps = []
        for block in self.blocks:
            h, att = block(h)
            maps.append(att)  # (B·C, H, L, L)
        y = self.decoder(h).reshape(B * C, -1) * scale[:, 0]  # (B·C, T'): back to input units
        y = y.reshape(B, C, -1)[:, :, :T].transpose(1, 2)  # (B, T, C)
        a = a.reshape(B, C, -1)[:, :, :T].transpose(1, 2)  # (B, T, C)
        return y, a, maps


# ----------------------------------------------------------------------------- scoring
def attention_features(maps: list[torch.Tensor], n_channels: int) -> torch.Tensor:
    """Per-token attention features (B, C, F, L) of every layer and head.

    ``maps``: one (B·C, H, L, L) softmax map per layer. Three features per layer and head, so
    F = 3 · layers · heads, ordered (layer, head, feature):
    the mass a token *receives* (column sum, mean 1 over tokens), the *entropy* of its own row and
    its *self-weight* (the diagonal: how much it attends to itself rather than to the window).
    """
    feats = []
    for att in maps:
        received = att.sum(dim=-2)  # (B·C, H, L)
        entropy = -(att * torch.log(att.clamp_min(1e-12))).sum(dim=-1)  # (B·C, H, L)
        self_weight = att.diagonal(dim1=-2, dim2=-1)  # (B·C, H, L)
        feats.append(torch.stack([received, entropy, self_weight], dim=2))  # (B·C, H, 3, L)
    f = torch.cat(feats, dim=1)  # (B·C, layers·H, 3, L)
    BC, _, _, L = f.shape
    return f.reshape(BC // n_channels, n_channels, -1, L)  # (B, C, F, L)


def window_relative_features(feats: NDArray[Any]) -> NDArray[Any]:
    """Features (N, C, F, L) minus their median over the window's tokens (the typical token).

    >>> f = np.array([1.0, 1.0, 1.0, 5.0]).reshape(1, 1, 1, 4)
    >>> window_relative_features(f).ravel().tolist()
    [0.0, 0.0, 0.0, 4.0]
    """
    return feats - np.median(feats, axis=-1, keepdims=True)


def torch_window_relative(feats: torch.Tensor) -> torch.Tensor:
    """:func:`window_relative_features` in torch, with numpy's median (the mean of the two middle
    values when the count is even)."""
    v = feats.sort(dim=-1).values
    n = v.shape[-1]
    med = v[..., n // 2] if n % 2 else (v[..., n // 2 - 1] + v[..., n // 2]) / 2
    return feats - med.unsqueeze(-1)


def window_relative_error(sq_error: NDArray[Any]) -> NDArray[Any]:
    """Squared error (N, T, C) divided by its median over each window's steps, per channel.

    >>> e = np.array([[[1.0], [2.0], [3.0], [40.0]]])
    >>> window_relative_error(e)[0, :, 0].tolist()
    [0.4, 0.8, 1.2, 16.0]
    """
    return sq_error / np.maximum(np.median(sq_error, axis=1, keepdims=True), 1e-12)


def robust_location_scale(values: NDArray[Any], axis: tuple[int, ...]) -> tuple[
        NDArray[Any], NDArray[Any]]:
    """Median and 1.4826 · MAD over ``axis`` (a std estimate that ignores the 10 % anomalies)."""
    med = np.median(values, axis=axis, keepdims=True)
    mad = MAD_TO_STD * np.median(np.abs(values - med), axis=axis, keepdims=True)
    return med, np.maximum(mad, 1e-6)


def tokens_to_steps(token_scores: NDArray[Any], patch: int, n_steps: int) -> NDArray[Any]:
    """Token scores (N, C, L) -> per-sample scores (N, T, C): each sample takes its token's score.

    >>> tokens_to_steps(np.array([[[1.0, 2.0]]]), patch=2, n_steps=3)[0, :, 0].tolist()
    [1.0, 1.0, 2.0]
    """
    return np.repeat(token_scores, patch, axis=-1)[..., :n_steps].transpose(0, 2, 1)


class AttentionFocusedTransformer(TorchDetector):
    Config: ClassVar[type[DetectorConfig]] = AFTConfig
    config: AFTConfig  # type: ignore[assignment]
    # fit_statistics fits every mode's statistics, so the mode can change after training.
    scoring_fields: ClassVar[tuple[str, ...]] = ("contamination", "scoring")
    scoring_modes: ClassVar[tuple[str, ...]] = SCORING_MODES

    keep_maps_ = False  # set while scoring with extras=True

    @property
    def report_maps(self) -> bool:
        """Scoring by attention, the attention maps show how the score was made."""
        return self.config.scoring == "attention"

    def build(self, n_steps: int, n_channels: int) -> nn.Module:
        if self.config.input_scale not in INPUT_SCALES:
            raise RailwatchError(f"input_scale must be one of {', '.join(INPUT_SCALES)}, got "
                                 f"{self.config.input_scale!r}")
        return AttentionFocusedNet(n_steps, self.config)

    def loss(self, xb: torch.Tensor) -> torch.Tensor:
        noisy = xb
        if self.model_.training and self.config.train_noise > 0:
            noisy = xb + self.config.train_noise * torch.randn_like(xb)
        y, _, _ = self.model_(noisy)
        return F.mse_loss(y, xb)

    def raw(self, xb: torch.Tensor) -> dict[str, torch.Tensor]:
        y, a, maps = self.model_(xb)
        out = {
            "residual": xb - y,  # (B, T, C)
            "log_input_attention": torch.log(a),  # (B, T, C)
            # Relative to the window's typical token here, per batch (cheaper than in numpy).
            "attention_relative": torch_window_relative(
                attention_features(maps, xb.shape[2])),  # (B, C, F, L)
        }
        if self.keep_maps_:
            B, C = xb.shape[0], xb.shape[2]
            out["input_attention"] = a  # (B, T, C)
            for i, att in enumerate(maps):
                out[f"attention_{i}"] = att.reshape(B, C, *att.shape[1:])  # (B, C, H, L, L)
        return out

    def _score(self, X: FloatArray, context: dict[str, FloatArray], extras: bool) -> Scores:
        self.keep_maps_ = extras  # full maps only on request: (N, C, H, L, L) per layer is large
        try:
            return super()._score(X, context, extras)
        finally:
            self.keep_maps_ = False

    # -- statistics ------------------------------------------------------------------------
    @staticmethod
    def _attention_relative(raw: dict[str, NDArray[Any]]) -> tuple[NDArray[Any], NDArray[Any]]:
        """Attention features relative to their window's typical token: (N, C, F, L), (N, C, T)."""
        enc = raw["attention_relative"]  # already relative (raw())
        inp = window_relative_features(raw["log_input_attention"].transpose(0, 2, 1))
        return enc, inp

    def attention_z(self, raw: dict[str, NDArray[Any]]) -> tuple[NDArray[Any], NDArray[Any]]:
        """Standardised window-relative attention deviations, from :meth:`raw_outputs`: encoder
        (N, C, F, L), input (N, T, C)."""
        enc, inp = self._attention_relative(raw)
        z_enc = (enc - self.stats_["enc_loc"]) / self.stats_["enc_scale"]
        z_inp = (inp - self.stats_["inp_loc"]) / self.stats_["inp_scale"]
        return z_enc, z_inp.transpose(0, 2, 1)

    def _attention_channel(self, raw: dict[str, NDArray[Any]]) -> NDArray[Any]:
        """Attention deviation per sample and channel (N, T, C): the root mean square of two equally
        weighted parts, the encoder's mean squared z-score (its token's, over layers, heads and
        features) and the input attention's squared z-score of the sample itself. The input
        attention is the only per-sample attention (the spike detector); weighted as one feature
        among 3 · layers · heads + 1 it was drowned by the encoder's."""
        z_enc, z_inp = self.attention_z(raw)
        n_steps = z_inp.shape[1]
        sq_enc = tokens_to_steps((z_enc**2).mean(axis=2), self.config.patch, n_steps)  # (N, T, C)
        return np.sqrt((sq_enc + z_inp**2) / 2)

    def reconstruction_channel(self, raw: dict[str, NDArray[Any]]) -> NDArray[Any]:
        """The log of each sample's squared reconstruction error relative to its window's
        (N, T, C), from :meth:`raw_outputs`."""
        # Floored: an error of exactly 0 (float32) would give −inf.
        sq_error = raw["residual"] ** 2
        return np.log(np.maximum(window_relative_error(sq_error), 1e-12))  # (N, T, C)

    def fit_statistics(self, raw: dict[str, NDArray[Any]]) -> None:
        enc, inp = self._attention_relative(raw)  # per channel and feature (layer, head, kind):
        self.stats_["enc_loc"], self.stats_["enc_scale"] = robust_location_scale(enc, axis=(0, 3))
        self.stats_["inp_loc"], self.stats_["inp_scale"] = robust_location_scale(inp, axis=(0, 2))
        for name, values in (("att", self._attention_channel(raw)),
                             ("rec", self.reconstruction_channel(raw))):
            loc, scale = robust_location_scale(values, axis=(0, 1))  # (1, 1, C)
            self.stats_[f"{name}_score_loc"], self.stats_[f"{name}_score_scale"] = loc, scale

    def scores_from_raw(self, raw: dict[str, NDArray[Any]], extras: bool) -> Scores:
        mode = self.config.scoring
        parts = []
        if mode in ("attention", "combined"):
            att = self._attention_channel(raw)
            parts.append((att - self.stats_["att_score_loc"]) / self.stats_["att_score_scale"])
        if mode in ("reconstruction", "combined"):
            rec = self.reconstruction_channel(raw)
            parts.append((rec - self.stats_["rec_score_loc"]) / self.stats_["rec_score_scale"])
        channel = (sum(parts) / len(parts)).astype(np.float32)  # (N, T, C)
        point = reduce_point_max(channel)
        more: dict[str, NDArray[Any]] = {}
        if extras:
            more = {k: v for k, v in raw.items() if k == "input_attention"
                    or k.startswith("attention_") and k != "attention_relative"}
        return Scores(instance=reduce_instance_max(point), point=point, channel=channel,
                      extras=more)
