"""The training loop every deep detector shares, and the device it runs on.

A deep detector subclasses :class:`TorchDetector` and supplies small hooks (the network, a loss,
the raw outputs its scoring uses, the scores from them); the loop owns the device (CUDA when
present, else the CPU; never hard-coded), seeding without touching the caller's random state,
mini-batches, the validation split carved from the training set, early stopping and progress.
Scoring reads the raw outputs through a :class:`Network`, a callable from a normalised batch to
arrays: :class:`TorchNetwork` runs the torch module, and an onnxruntime session
(:class:`railwatch.deploy.onnx.OnnxNetwork`, loaded by :func:`railwatch.deploy.onnx.load_onnx`)
implements the same protocol.
"""

from __future__ import annotations

import hashlib
import logging
import math
from abc import abstractmethod
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import Any, ClassVar, Protocol

import numpy as np
import torch
from numpy.typing import NDArray

from railwatch.detectors import model_folder
from railwatch.detectors.api import (
    GLR_SCORING,
    Detector,
    DetectorConfig,
    FloatArray,
    Scores,
    TrainConfig,
)
from railwatch.errors import RailwatchError, one_line
from railwatch.progress import Progress
from railwatch.scoring.reduce import reduce_instance_max, reduce_point_max
from railwatch.scoring.residual import ResidualGLR
from railwatch.scoring.thresholds import ContaminationQuantile

log = logging.getLogger(__name__)


def resolve_device(name: str) -> torch.device:
    """``auto`` picks CUDA when present, else the CPU; never hard-coded."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        return torch.device(name)
    except RuntimeError as e:
        raise RailwatchError(f"unknown device {name!r}: {e}") from None


@contextmanager
def seeded(seed: int) -> Iterator[None]:
    """Seed torch inside the block without touching the caller's global random state."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        yield


class Network(Protocol):
    """What scoring needs of a network: a normalised batch of windows (B, T, C) float32 to its
    raw outputs, each an array (B, ...)."""

    def __call__(self, batch: NDArray[np.float32]) -> dict[str, NDArray[Any]]: ...


class TorchNetwork:
    """The :class:`Network` of a torch detector: its module on its device, without gradients."""

    def __init__(self, detector: TorchDetector) -> None:
        self.detector = detector

    @torch.no_grad()
    def __call__(self, batch: NDArray[np.float32]) -> dict[str, NDArray[Any]]:
        det = self.detector
        det.model_.eval()
        out = det.raw(torch.from_numpy(batch).to(det.device_))
        return {k: v.float().cpu().numpy() for k, v in out.items()}


class TorchDetector(Detector):
    """A detector backed by a PyTorch module, trained by the shared loop.

    Hooks: :meth:`build` (the module for a window shape), :meth:`loss` (a training loss of a
    batch), :meth:`raw` (per-batch outputs used for scoring), :meth:`fit_statistics` (score
    statistics from the validation split's raw outputs) and :meth:`scores_from_raw`. A model with
    an unusual update (the Anomaly Transformer's minimax) overrides :meth:`train_step`.
    """

    Config: ClassVar[type[DetectorConfig]] = TrainConfig
    config: TrainConfig  # type: ignore[assignment]

    # -- hooks -----------------------------------------------------------------------------
    @abstractmethod
    def build(self, n_steps: int, n_channels: int) -> torch.nn.Module:
        """The network for windows of ``n_steps`` × ``n_channels``."""

    @abstractmethod
    def loss(self, xb: torch.Tensor) -> torch.Tensor:
        """Training loss of a batch (B, T, C) on ``self.model_``."""

    @abstractmethod
    def raw(self, xb: torch.Tensor) -> dict[str, torch.Tensor]:
        """Per-window outputs needed for scoring (each (B, ...)), computed without gradients."""

    def fit_statistics(self, raw: dict[str, NDArray[Any]]) -> None:
        """Fit score statistics (into ``stats_``) from the validation split's raw outputs."""

    @abstractmethod
    def scores_from_raw(self, raw: dict[str, NDArray[Any]], extras: bool) -> Scores:
        """Scores from raw outputs and the fitted statistics."""

    def make_optimizer(self) -> torch.optim.Optimizer:
        return torch.optim.Adam(self.model_.parameters(), lr=self.config.lr)

    def on_epoch_end(self, epoch: int) -> None:
        """Called after each training epoch (e.g. a learning-rate schedule)."""

    def train_step(self, xb: torch.Tensor) -> float:
        """One optimiser step on a batch; returns the loss."""
        self.optimizer_.zero_grad(set_to_none=True)
        loss = self.loss(xb)
        loss.backward()
        self.optimizer_.step()
        return float(loss.detach())

    def validation_loss(self, xb: torch.Tensor) -> float:
        return float(self.loss(xb))

    # -- the loop --------------------------------------------------------------------------
    def _fit(self, X: FloatArray, context: dict[str, FloatArray]) -> None:
        cfg = self.config
        self.fit_residual_, self.fit_digest_ = None, ""  # of the network trained before
        self.device_ = resolve_device(cfg.device)
        rng = np.random.default_rng(cfg.seed)
        order = rng.permutation(len(X))
        n_val = int(round(cfg.val_fraction * len(X))) if len(X) >= 10 else 0
        val_idx, train_idx = order[:n_val], order[n_val:]
        train, val = X[train_idx], X[val_idx] if n_val else X[train_idx]
        with seeded(cfg.seed):
            self.model_ = self.build(self.n_steps_, self.n_channels_).to(self.device_)
            self.optimizer_ = self.make_optimizer()
            gen = torch.Generator().manual_seed(cfg.seed)
            xt = torch.from_numpy(train)
            best, best_state, stale = math.inf, None, 0
            bar = Progress(cfg.epochs, type(self).__name__, "epochs", enabled=cfg.progress,
                           every_s=0.0)
            for epoch in range(cfg.epochs):
                self.model_.train()
                perm = torch.randperm(len(xt), generator=gen)
                losses = [self.train_step(xt[perm[i:i + cfg.batch_size]].to(self.device_))
                          for i in range(0, len(xt), cfg.batch_size)]
                self.on_epoch_end(epoch)
                val_loss = self._evaluate(val)
                bar.set_postfix_str(f"loss {np.mean(losses):.4f}, validation {val_loss:.4f}")
                bar.update(1)
                log.debug("epoch %d: train %.5f, validation %.5f", epoch + 1,
                          np.mean(losses), val_loss)
                if val_loss < best - 1e-6:
                    best, stale = val_loss, 0
                    best_state = {k: v.detach().clone() for k, v in
                                  self.model_.state_dict().items()}
                else:
                    stale += 1
                    if cfg.patience and stale >= cfg.patience:
                        log.info("early stop after epoch %d (validation loss %.5f)", epoch + 1,
                                 best)
                        break
            bar.close()
            if best_state is not None:
                self.model_.load_state_dict(best_state)
        self.model_.eval()
        del self.optimizer_
        self.fit_statistics(self.raw_outputs(val))

    @torch.no_grad()
    def _evaluate(self, X: FloatArray) -> float:
        self.model_.eval()
        total, count = 0.0, 0
        for i in range(0, len(X), 256):
            xb = torch.from_numpy(X[i:i + 256]).to(self.device_)
            total += self.validation_loss(xb) * len(xb)
            count += len(xb)
        return total / max(count, 1)

    #: The network scoring runs (:class:`Network`); None: the torch module (:class:`TorchNetwork`).
    #: A detector loaded from ONNX holds an onnxruntime session here.
    network_: Network | None = None

    def network(self) -> Network:
        """The network that computes the raw outputs for scoring."""
        return self.network_ if self.network_ is not None else TorchNetwork(self)

    def raw_outputs(self, X: FloatArray) -> dict[str, NDArray[Any]]:
        """The network's raw outputs (name → array, one row per window) of windows already
        :meth:`normalized`, in batches of ``batch_size``: what the scoring starts from (a public
        hook for research scripts that look inside a detector, such as benchmarks/)."""
        network = self.network()
        parts: dict[str, list[NDArray[Any]]] = {}
        for i in range(0, len(X), self.config.batch_size):
            for k, v in network(np.ascontiguousarray(X[i:i + self.config.batch_size])).items():
                parts.setdefault(k, []).append(v)
        return {k: np.concatenate(v) for k, v in parts.items()}

    def _score(self, X: FloatArray, context: dict[str, FloatArray], extras: bool) -> Scores:
        return self._scores_of_raw(self.raw_outputs(X), X.shape[1], extras)

    def _scores_of_raw(self, raw: dict[str, NDArray[Any]], n_steps: int, extras: bool) -> Scores:
        if getattr(self.config, "scoring", None) == GLR_SCORING:
            return self.glr_scores(raw, n_steps, extras)
        return self.scores_from_raw(raw, extras)

    #: The signed residual (``raw["residual"]``) of the windows the threshold was last fitted on,
    #: where the network has one, and a digest of those windows: :meth:`rescored` into the GLR
    #: scoring on the same windows scans it instead of running the network over them again (the
    #: benchmark's ``+glr`` rows share their model's training). Kept in memory, never saved.
    fit_residual_: NDArray[Any] | None = None
    fit_digest_: str = ""

    def _fit_threshold(self, X: FloatArray, context: dict[str, FloatArray]) -> None:
        digest = hashlib.blake2b(np.ascontiguousarray(X).data, digest_size=16).hexdigest()
        if getattr(self.config, "scoring", None) == GLR_SCORING and \
                self.fit_residual_ is not None and self.fit_digest_ == digest:
            scores = self.glr_scores({"residual": self.fit_residual_}, X.shape[1], False)
        else:
            raw = self.raw_outputs(X)
            self.fit_residual_, self.fit_digest_ = raw.get("residual"), digest
            scores = self._scores_of_raw(raw, X.shape[1], False)
        self.decision_scores_ = scores.instance
        self.set_threshold(ContaminationQuantile(self.config.contamination))

    # -- the shared GLR scoring (``scoring=glr``) -----------------------------------------
    def residual_stride(self) -> int:
        """Samples per value of the model's ``residual`` raw output (MSCRED: one per step)."""
        return 1

    def glr_scores(self, raw: dict[str, NDArray[Any]], n_steps: int, extras: bool) -> Scores:
        """``scoring=glr``: the model's signed residual ``raw["residual"]`` (input minus
        reconstruction, (N, T / stride, C)) standardised by a noise scale estimated from it
        (window median removed, at most one change of level per window and channel) and tested
        for a spike and 5–20-sample boxes by the calibrated GLR scan
        (:class:`railwatch.scoring.residual.ResidualGLR`); point = max over channels, instance =
        max over time. Nothing is fitted: the scan is calibrated on simulated N(0, 1) windows."""
        channel = ResidualGLR(seed=self.config.seed).sample_scores(
            raw["residual"], self.residual_stride(), n_steps)
        point = reduce_point_max(channel)
        return Scores(instance=reduce_instance_max(point), point=point, channel=channel,
                      extras={"residual": raw["residual"]} if extras else {})

    def _state_dict(self) -> dict[str, torch.Tensor]:
        return {k: v.detach().cpu() for k, v in self.model_.state_dict().items()}

    def _load_state(self, state: dict[str, torch.Tensor] | None) -> None:
        if state is None:
            raise RailwatchError(f"the model directory has no {model_folder.WEIGHTS}")
        if not isinstance(state, Mapping) or not all(
                isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()):
            raise RailwatchError(f"{model_folder.WEIGHTS} does not hold network weights (a "
                                 "state_dict)")
        self.device_ = resolve_device(self.config.device)
        with seeded(self.config.seed):
            self.model_ = self.build(self.n_steps_, self.n_channels_)
        try:
            self.model_.load_state_dict(state)
        except RuntimeError as e:
            raise RailwatchError(f"{model_folder.WEIGHTS} does not fit the {type(self).__name__} "
                                 f"network of this config: {one_line(e)[:200]}") from None
        self.model_.to(self.device_).eval()
