"""MSCRED (Zhang et al. 2019): multi-scale signature matrices, attention ConvLSTM, broken entries.

Pipeline (``docs/detectors.md``, "MSCRED"), for windows ``X`` (N, T, C):

1. **Min-max normalisation** per channel with the minimum and maximum of the training windows
   (``stats_["input_min"]``, ``stats_["input_range"]``), to [-1, 1] rather than [0, 1]. The base
   class's standardisation is switched off (``normalize = False``): min-max of standardised data
   equals min-max of the raw data. Why [-1, 1]: the vibration is centred, so on [0, 1] every
   product carries a 0.25 offset plus a term linear in the signal, and ``M`` becomes a low-pass
   (aliased at the 10-sample step rate) copy of the signal rather than its local power; measured on
   stage 1 (5 epochs), instance ROC-AUC 0.69 on [0, 1] against 0.80 on [-1, 1].
2. **Signature matrices** (:func:`signature_matrices`): for each step ``k`` ending at sample
   ``t_k = min(gap·k + gap − 1, T − 1)`` (``gap = 10``: 20 steps per 200-sample window) and each
   scale ``w ∈ {10, 30, 60}``, ``M_ij = Σ_{δ<w} x_i(t−δ) x_j(t−δ) / w``; the window is padded on the
   left by reflection so that every scale is defined at the first steps. Computed with cumulative
   sums of the outer products, no loop over windows or steps. Matrices of fewer than 8 channels are
   zero-padded to 8×8 (:func:`pad_matrices`, the TimeEval precedent).
3. **Network** (:class:`MSCREDNet`): a four-level conv encoder (32 3×3 s1, 64 3×3 s2, 128 2×2 s2,
   256 2×2 s2, SELU; ``filters`` sets the widths: the default (4, 8, 16, 32) is an eighth of the
   paper's, which cost ~6 s per 32 windows on one CPU core; pass ``filters=(32, 64, 128, 256)``
   for the paper's sizes) applied to every step; at each level an attention
   ConvLSTM runs a real recurrence over the ``h = 5`` steps ending at the step to reconstruct and
   mixes its hidden states with the parameter-free attention ``α_i = softmax_i(⟨H_i, H_h⟩ / h)``;
   a transposed-conv decoder with skip concatenation of the attention outputs reconstructs the last
   step's matrices (all scales). Every step of a window is reconstructed from its own sliding
   sequence; the first steps' missing history repeats step 0. MSE loss over the real (unpadded)
   entries.
4. **Score**: the squared residual of the smallest scale (w = 10) at each step. ``θ`` is the
   ``theta_quantile`` quantile of the validation split's residuals (real entries). Step score =
   number of "broken" entries (residual > θ) + ``m / (m + θ)`` with ``m`` the mean residual, a
   tie-breaker in [0, 1) that never outranks one more broken entry. Each step's score covers its
   ``gap`` samples (``point``); ``channel[..., c]`` is the same score computed on residual row
   ``c`` (real channels only). ``instance`` = max over time of ``point`` (the spec's default).
5. ``scoring="glr"`` (not the paper's): MSCRED reconstructs matrices, not samples, so its signed
   residual is the diagonal of the smallest scale's residual matrix, each channel's local power
   over the ``w`` samples of a step (``w = gap = 10``: the steps do not overlap), one value per
   ``gap`` samples; the shared GLR scan tests it at that resolution
   (``ResidualGLR.sample_scores``).

CPU cost. The input-to-hidden convolutions of the ConvLSTMs and the encoder run once per step and
are shared by the (up to) five sequences that contain that step; only the hidden-to-hidden
convolutions run per sequence. Training reconstructs ``train_sequences`` randomly chosen steps of
each window per batch (a fresh draw every batch), scoring reconstructs all of them.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn
from torch.nn import functional as F

from railwatch.detectors.api import GLR_SCORING, DetectorConfig, FloatArray, Scores, TrainConfig
from railwatch.detectors.training import TorchDetector
from railwatch.scoring.reduce import reduce_instance_max

log = logging.getLogger(__name__)

CL = torch.channels_last  # 2-4x faster small convolutions on the CPU (oneDNN), same results
MIN_SIZE = 8  # matrices of fewer channels are zero-padded to 8×8 (spec)


@dataclass(frozen=True)
class MSCREDConfig(TrainConfig):
    scales: tuple[int, ...] = (10, 30, 60)  # signature-matrix windows w, in samples (spec)
    gap: int = 10  # samples between step end times (spec)
    history: int = 5  # h: steps in each ConvLSTM sequence (spec)
    filters: tuple[int, ...] = (4, 8, 16, 32)  # level widths; the paper's: (32, 64, 128, 256)
    train_sequences: int = 2  # steps reconstructed per window in each training batch (0: all)
    theta_quantile: float = 0.995  # θ: this quantile of the validation residuals
    epochs: int = 4  # CPU budget: every step is its own 5-step sequence (see CPU cost)
    lr: float = 3e-3
    patience: int = 5
    scoring: str = "paper"  # "paper" (broken entries, 4. above) or "glr" (5. above)


# ----------------------------------------------------------------------------- signature matrices
def step_ends(n_steps: int, gap: int) -> NDArray[np.int64]:
    """End sample of each step: ``min(gap·k + gap − 1, T − 1)``, k = 0 .. ceil(T / gap) − 1.

    >>> step_ends(25, 10).tolist()
    [9, 19, 24]
    """
    n_sig = -(-n_steps // gap)
    return np.minimum(np.arange(n_sig) * gap + gap - 1, n_steps - 1)


def signature_matrices(x: torch.Tensor, scales: tuple[int, ...], gap: int) -> torch.Tensor:
    """Signature matrices of windows ``x`` (B, T, C) -> (B, K, S, C, C), K = ceil(T / gap).

    ``out[b, k, s, i, j] = Σ_{δ<w_s} x_i(t_k − δ) x_j(t_k − δ) / w_s`` with ``t_k`` from
    :func:`step_ends`; samples before the window start come from a reflection of its left edge
    (replication when the window is too short to reflect). Vectorised with a cumulative sum of the
    outer products ``x(t) x(t)ᵀ``, in float64 to keep the differences exact.
    """
    n_steps = x.shape[1]
    pad = max(scales) - 1
    h = x.transpose(1, 2).double()  # (B, C, T)
    if pad:
        mode = "reflect" if pad < n_steps else "replicate"
        h = F.pad(h, (pad, 0), mode=mode)
    h = h.transpose(1, 2)  # (B, P + T, C)
    outer = h.unsqueeze(3) * h.unsqueeze(2)  # (B, P + T, C, C)
    csum = F.pad(outer.cumsum(dim=1), (0, 0, 0, 0, 1, 0))  # (B, 1 + P + T, C, C), csum[0] = 0
    ends = torch.as_tensor(step_ends(n_steps, gap), device=x.device) + pad + 1  # in csum indices
    mats = [(csum[:, ends] - csum[:, ends - w]) / w for w in scales]  # each (B, K, C, C)
    return torch.stack(mats, dim=2).to(x.dtype)


def pad_matrices(m: torch.Tensor, size: int = MIN_SIZE) -> torch.Tensor:
    """Zero-pad the last two dims (C, C) of ``m`` to (size, size) when C < size (the spec's 8×8)."""
    extra = size - m.shape[-1]
    return F.pad(m, (0, extra, 0, extra)) if extra > 0 else m


def sequence_index(n_sig: int, ends: torch.Tensor, history: int) -> torch.Tensor:
    """Step indices (B, E, h) of the sequences of ``history`` steps ending at ``ends`` (B, E);
    history before step 0 repeats step 0 (spec: "pad the first steps' history by repeating").

    >>> sequence_index(20, torch.tensor([[0, 2, 19]]), 5).tolist()
    [[[0, 0, 0, 0, 0], [0, 0, 0, 1, 2], [15, 16, 17, 18, 19]]]
    """
    offsets = torch.arange(-history + 1, 1, device=ends.device)
    return (ends[..., None] + offsets).clamp(0, n_sig - 1)


# ----------------------------------------------------------------------------- network
class SameConv2d(nn.Conv2d):
    """Conv2d with TensorFlow's ``same`` padding (the extra row/column of an even kernel goes
    right/bottom), so that stride 2 halves the size and stride 1 keeps it."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        k, s = self.kernel_size[0], self.stride[0]
        size = x.shape[-1]
        total = max((-(-size // s) - 1) * s + k - size, 0)
        x = F.pad(x, (total // 2, total - total // 2, total // 2, total - total // 2))
        return super().forward(x.contiguous(memory_format=CL))


class AttentionConvLSTM(nn.Module):
    """ConvLSTM over a sequence of steps with MSCRED's parameter-free temporal attention.

    The input-to-hidden convolution (with the bias) takes each distinct step once; the
    hidden-to-hidden convolution runs inside the recurrence. Gates i, f, o, g as in Shi et al. 2015
    (no peepholes, as the paper's ``ConvLSTMCell``).
    """

    def __init__(self, channels: int, kernel: int) -> None:
        super().__init__()
        self.channels = channels
        self.x_conv = SameConv2d(channels, 4 * channels, kernel)
        self.h_conv = SameConv2d(channels, 4 * channels, kernel, bias=False)

    def forward(self, feats: torch.Tensor, seq_index: torch.Tensor) -> torch.Tensor:
        """``feats`` (B, K, F, H, W) of every step; ``seq_index`` (B, E, h) step indices of the
        E sequences to run per window. Returns the attention outputs (B, E, F, H, W)."""
        b, k, f, hh, ww = feats.shape
        gx = self.x_conv(feats.reshape(b * k, f, hh, ww))  # (B·K, 4F, H, W), once per step
        e, n_hist = seq_index.shape[1], seq_index.shape[2]
        rows = k * torch.arange(b, device=feats.device)[:, None, None]
        flat = (seq_index + rows).reshape(-1, n_hist)  # (B·E, h) rows of gx
        h = c = None
        states = []
        for i in range(n_hist):  # the real recurrence over the h steps (paper, Eq. 3)
            gates = gx.index_select(0, flat[:, i])  # (B·E, 4F, H, W)
            if h is not None:
                gates = gates.add_(self.h_conv(h))
            ifo = torch.sigmoid(gates[:, :3 * f])
            g = torch.tanh(gates[:, 3 * f:])
            c = ifo[:, :f] * g if c is None else ifo[:, f:2 * f] * c + ifo[:, :f] * g
            h = ifo[:, 2 * f:] * torch.tanh(c)
            states.append(h)
        hs = torch.stack(states, dim=1)  # (B·E, h, F, H, W)
        # Temporal attention (paper, Eq. 4): α_i = softmax_i(⟨H_i, H_h⟩ / h), output Σ α_i H_i.
        logits = (hs * hs[:, -1:]).flatten(2).sum(dim=2) / n_hist  # (B·E, h)
        alpha = torch.softmax(logits, dim=1)
        out = (alpha[:, :, None, None, None] * hs).sum(dim=1)  # (B·E, F, H, W)
        return out.reshape(b, e, f, hh, ww)


class MSCREDNet(nn.Module):
    """Signature matrices (B, K, S, D, D) -> reconstructions (B, E, S, D, D) of E chosen steps.

    D ≥ 8 (zero-padded). Encoder kernels 3, 3, 2, 2 with strides 1, 2, 2, 2 (8×8 -> 8, 4, 2, 1);
    ConvLSTM kernels 3, 3, 2, 2 as in the paper; decoder: transposed convs mirroring the encoder,
    each level's input concatenated with that level's attention output (skip connections).
    """

    kernels = (3, 3, 2, 2)
    strides = (1, 2, 2, 2)

    def __init__(self, n_scales: int, filters: tuple[int, ...], history: int) -> None:
        super().__init__()
        if len(filters) != 4:
            raise ValueError(f"filters must name 4 encoder widths, got {filters}")
        self.history = history
        chans = (n_scales, *filters)
        self.encoder = nn.ModuleList(
            SameConv2d(chans[i], chans[i + 1], k, stride=s)
            for i, (k, s) in enumerate(zip(self.kernels, self.strides, strict=True)))
        self.lstms = nn.ModuleList(AttentionConvLSTM(f, k)
                                   for f, k in zip(filters, self.kernels, strict=True))
        f1, f2, f3, f4 = filters
        self.dec4 = nn.ConvTranspose2d(f4, f3, 2, stride=2)  # 1 -> 2
        self.dec3 = nn.ConvTranspose2d(2 * f3, f2, 2, stride=2)  # 2 -> 4
        self.dec2 = nn.ConvTranspose2d(2 * f2, f1, 3, stride=2, padding=1, output_padding=1)  # 4->8
        self.dec1 = nn.Conv2d(2 * f1, n_scales, 3, padding=1)  # linear head, 8 -> 8

    def forward(self, sig: torch.Tensor, ends: torch.Tensor) -> torch.Tensor:
        b, k, s, d, _ = sig.shape
        index = sequence_index(k, ends, self.history)
        h = sig.reshape(b * k, s, d, d)
        skips = []
        for conv, lstm in zip(self.encoder, self.lstms, strict=True):
            h = F.selu(conv(h))  # (B·K, F_l, D_l, D_l)
            skips.append(lstm(h.reshape(b, k, *h.shape[1:]), index).flatten(0, 1))  # (B·E, ...)
        a1, a2, a3, a4 = skips
        y = F.selu(self.dec4(a4.contiguous(memory_format=CL)))
        y = F.selu(self.dec3(torch.cat([y, a3], dim=1).contiguous(memory_format=CL)))
        y = F.selu(self.dec2(torch.cat([y, a2], dim=1).contiguous(memory_format=CL)))
        y = self.dec1(torch.cat([y, a1], dim=1).contiguous(memory_format=CL))  # (B·E, S, D, D)
        return y.reshape(b, -1, s, d, d)


# ----------------------------------------------------------------------------- scores
def broken_score(residual: NDArray[Any], theta: float, axis: tuple[int, ...]) -> NDArray[Any]:
    """Number of entries above ``theta`` plus the tie-breaker ``m / (m + θ)`` ∈ [0, 1), ``m`` the
    mean residual, reducing ``axis``.

    >>> r = np.array([[0.0, 3.0], [1.0, 0.5]])
    >>> broken_score(r, 1.0, axis=(0, 1)).round(4).item()
    1.5294
    """
    n_broken = (residual > theta).sum(axis=axis)
    m = residual.mean(axis=axis)
    return n_broken + m / (m + theta)


class MSCRED(TorchDetector):
    Config: ClassVar[type[DetectorConfig]] = MSCREDConfig
    config: MSCREDConfig  # type: ignore[assignment]
    normalize: ClassVar[bool] = False  # min-max normalisation instead (see the module docstring)
    scoring_fields: ClassVar[tuple[str, ...]] = ("contamination", "scoring")
    scoring_modes: ClassVar[tuple[str, ...]] = ("paper", GLR_SCORING)

    def _fit(self, X: FloatArray, context: dict[str, FloatArray]) -> None:
        lo, hi = X.min(axis=(0, 1)), X.max(axis=(0, 1))  # (C,) per-channel training range
        self.stats_["input_min"] = lo.astype(np.float32)
        self.stats_["input_range"] = np.where(hi - lo > 1e-8, hi - lo, 1.0).astype(np.float32)
        super()._fit(X, context)

    def build(self, n_steps: int, n_channels: int) -> nn.Module:
        cfg = self.config
        if min(cfg.scales) < 1 or cfg.gap < 1 or cfg.history < 1:
            raise ValueError(f"scales, gap and history must be positive: {cfg}")
        return MSCREDNet(len(cfg.scales), cfg.filters, cfg.history)

    def _signatures(self, xb: torch.Tensor) -> torch.Tensor:
        """Windows (B, T, C) -> zero-padded signature matrices (B, K, S, D, D), D = max(C, 8)."""
        lo = torch.as_tensor(self.stats_["input_min"], device=xb.device)
        rng = torch.as_tensor(self.stats_["input_range"], device=xb.device)
        scaled = 2.0 * (xb - lo) / rng - 1.0  # min-max to [-1, 1]
        m = signature_matrices(scaled, self.config.scales, self.config.gap)
        return pad_matrices(m)

    def _reconstruct(self, xb: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(target, reconstruction) of every step's real C×C entries, each (B, K, S, C, C)."""
        sig = self._signatures(xb)
        b, k = sig.shape[:2]
        recon = self.model_(sig, torch.arange(k, device=xb.device).expand(b, k))
        c = xb.shape[2]
        return sig[..., :c, :c], recon[..., :c, :c]

    def loss(self, xb: torch.Tensor) -> torch.Tensor:
        cfg = self.config
        n_sig = -(-xb.shape[1] // cfg.gap)
        if not (self.model_.training and 0 < cfg.train_sequences < n_sig):
            target, recon = self._reconstruct(xb)
            return F.mse_loss(recon, target)
        # Training: a fresh random subset of end steps per window and batch (seeded by the loop),
        # each sequence of h steps run on its own so that unused steps cost nothing.
        sig = self._signatures(xb)  # (B, K, S, D, D)
        ends = torch.rand(len(xb), n_sig).argsort(dim=1)[:, :cfg.train_sequences].to(xb.device)
        index = sequence_index(n_sig, ends, cfg.history)  # (B, E, h)
        seqs = sig[torch.arange(len(xb), device=xb.device)[:, None, None], index].flatten(0, 1)
        last = torch.full((len(seqs), 1), cfg.history - 1, device=xb.device)
        recon = self.model_(seqs, last)[:, 0]  # (B·E, S, D, D)
        c = xb.shape[2]
        return F.mse_loss(recon[..., :c, :c], seqs[:, -1, :, :c, :c])

    def raw(self, xb: torch.Tensor) -> dict[str, torch.Tensor]:
        target, recon = self._reconstruct(xb)
        diff = target[:, :, 0] - recon[:, :, 0]  # (B, K, C, C), smallest w
        return {"sq_residual": diff**2,
                "residual": torch.diagonal(diff, dim1=-2, dim2=-1)}  # (B, K, C): local power

    def residual_stride(self) -> int:
        return self.config.gap

    def fit_statistics(self, raw: dict[str, NDArray[Any]]) -> None:
        theta = np.quantile(raw["sq_residual"], self.config.theta_quantile)
        self.stats_["theta"] = np.array(max(float(theta), 1e-12))

    def scores_from_raw(self, raw: dict[str, NDArray[Any]], extras: bool) -> Scores:
        r = raw["sq_residual"]  # (N, K, C, C)
        theta = float(self.stats_["theta"])
        step = broken_score(r, theta, axis=(2, 3))  # (N, K)
        rows = broken_score(r, theta, axis=(3,))  # (N, K, C): residual row of each channel
        sample_step = np.arange(self.n_steps_) // self.config.gap  # each step covers its samples
        point = step[:, sample_step].astype(np.float32)  # (N, T)
        channel = rows[:, sample_step].astype(np.float32)  # (N, T, C)
        return Scores(instance=reduce_instance_max(point), point=point, channel=channel)
