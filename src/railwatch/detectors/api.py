"""The detector API every model shares: configs, input checks, ``Scores`` and :class:`Detector`.

Contract (``docs/detectors.md``), in the style of scikit-learn and PyOD:

- ``fit(X) -> self`` learns everything: per-channel input normalisation, weights, score
  statistics and ``threshold_``, the ``1 − contamination`` quantile of the training instance scores.
  Learned state ends in ``_``; nothing happens in ``__init__`` but storing the config.
- ``score(X) -> Scores`` with ``instance`` (N,), ``point`` (N, T) and ``channel`` (N, T, C);
  higher is more anomalous.
- ``localize``, ``predict``, ``save`` (a model folder: :mod:`railwatch.detectors.model_folder`;
  :func:`railwatch.detectors.registry.load_detector` reads it back).

Capabilities are class attributes (tags, as scikit-learn's estimator tags): ``normalize``,
``fixed_length``, ``needs``, ``scoring_fields``, ``scoring_modes``; ``report_maps`` is a property
(it may depend on the scoring mode). This module does not import torch: deep detectors subclass
:class:`railwatch.detectors.training.TorchDetector`, which owns the device, seeding, batching,
the validation split, early stopping and progress.
"""

from __future__ import annotations

import os
import warnings
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from railwatch.detectors import model_folder
from railwatch.errors import RailwatchError, one_line
from railwatch.scoring.reduce import (
    Localization,
    localize,
    reduce_instance_max,
    reduce_point_max,
)
from railwatch.scoring.residual import MAD_TO_STD
from railwatch.scoring.thresholds import ContaminationQuantile, ThresholdRule

if TYPE_CHECKING:
    import torch

FloatArray = NDArray[np.float32]
#: The ``scoring`` mode that scores a model's residual by the shared GLR scan.
GLR_SCORING = "glr"


# ----------------------------------------------------------------------------- configs
@dataclass(frozen=True)
class DetectorConfig:
    """Settings every detector has. Subclasses add their own fields with defaults."""

    contamination: float = 0.10  # expected anomaly share: sets threshold_
    seed: int = 0
    fs: float = 100.0  # Hz, only used to report localised times in seconds
    batch_size: int = 32  # scoring batch (and training batch for deep models)
    progress: bool = True  # progress bar on long work (off when not a TTY)


@dataclass(frozen=True)
class TrainConfig(DetectorConfig):
    """Settings of the shared training loop (Adam, mini-batches, early stopping)."""

    epochs: int = 20
    lr: float = 1e-3
    val_fraction: float = 0.10  # validation split carved from the training set
    patience: int = 3  # epochs without validation improvement before stopping (0: never stop)
    device: str = "auto"  # "auto" (cuda if present, else cpu), "cpu", "cuda", "cuda:1", ...


def config_from_dict(cls: type[DetectorConfig], values: Mapping[str, Any]) -> DetectorConfig:
    """Build ``cls`` from overrides, rejecting unknown keys and converting/validating types."""
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise RailwatchError(
            f"unknown config key{'s' if len(unknown) > 1 else ''} {', '.join(unknown)} for "
            f"{cls.__name__}; valid keys: {', '.join(sorted(known))}"
        )
    defaults = cls()
    converted = {k: _coerce(k, v, getattr(defaults, k)) for k, v in values.items()}
    return replace(defaults, **converted)


def _coerce(key: str, value: Any, default: Any) -> Any:
    """Convert ``value`` (possibly a string from ``--set key=value``) to the default's type."""
    kind = type(default)
    try:
        if isinstance(default, bool):
            if isinstance(value, str):
                low = value.strip().lower()
                if low not in {"true", "false", "1", "0", "yes", "no"}:
                    raise ValueError(value)
                return low in {"true", "1", "yes"}
            if not isinstance(value, bool | int):
                raise ValueError(value)
            return bool(value)
        if isinstance(default, int):
            if isinstance(value, float) and not value.is_integer():
                raise ValueError(value)
            return int(value)
        if isinstance(default, float):
            return float(value)
        if isinstance(default, tuple):
            items = [v for v in value.split(",") if v.strip()] if isinstance(value, str) \
                else list(value)  # "" is the empty tuple
            inner = type(default[0]) if default else str
            return tuple(inner(v) for v in items)
        if isinstance(default, str):
            return str(value)
    except (TypeError, ValueError):
        pass
    else:
        return value
    raise RailwatchError(f"config key {key}: expected {kind.__name__}, got {value!r}")


# ----------------------------------------------------------------------------- data checks
def check_windows(
    X: Any, *, n_channels: int | None = None, n_steps: int | None = None
) -> FloatArray:
    """Validate windows (N, T, C) and return them as a float32 array.

    Raises a one-line :class:`RailwatchError` naming the problem: wrong rank, empty, wrong channel
    count or window length against the fitted model, non-numeric values, NaN or inf (with the
    first position).
    """
    try:
        arr = np.asarray(X)
    except (TypeError, ValueError) as e:
        raise RailwatchError(f"windows must be a numeric array: {e}") from None
    if arr.dtype.kind not in "fiub":
        raise RailwatchError(f"windows must be numeric, got dtype {arr.dtype}")
    if arr.ndim != 3:
        raise RailwatchError(
            f"expected windows of shape (n_windows, n_steps, n_channels), got shape {arr.shape}"
        )
    if arr.shape[0] == 0 or arr.shape[1] == 0 or arr.shape[2] == 0:
        raise RailwatchError(f"no data: windows have shape {arr.shape}")
    if n_channels is not None and arr.shape[2] != n_channels:
        raise RailwatchError(
            f"expected {_plural(n_channels, 'channel')}, got {arr.shape[2]}: the detector was "
            f"fitted on {n_channels}-channel data"
        )
    if n_steps is not None and arr.shape[1] != n_steps:
        raise RailwatchError(
            f"expected windows of {n_steps} steps, got {arr.shape[1]}: this detector needs the "
            "window length it was fitted on"
        )
    arr = arr.astype(np.float32, copy=False)
    finite = np.isfinite(arr)
    if not finite.all():
        w, t, c = np.argwhere(~finite)[0]
        what = "NaN" if np.isnan(arr[w, t, c]) else "inf"
        raise RailwatchError(
            f"input contains {what} at window {w}, step {t}, channel {c} "
            f"({(~finite).sum()} non-finite values in all): clean or drop those windows"
        )
    return arr


def _plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


# ----------------------------------------------------------------------------- scores
@dataclass(frozen=True)
class Scores:
    """Anomaly scores of N windows; higher is more anomalous."""

    instance: FloatArray  # (N,)
    point: FloatArray  # (N, T)
    channel: FloatArray  # (N, T, C)
    extras: dict[str, NDArray[Any]] = field(default_factory=dict)  # e.g. attention maps


# ----------------------------------------------------------------------------- detectors
class Detector(ABC):
    """Base of every detector. Subclasses implement :meth:`_fit` and :meth:`_score`.

    Class attributes a subclass may set:
    ``Config`` (its config dataclass), ``normalize`` (per-channel standardisation of inputs from
    training statistics, default on), ``fixed_length`` (scoring needs the fitted window length),
    ``needs`` (names of side arrays, e.g. the oracle's generator components, that ``fit`` and
    ``score`` must receive in ``context``), ``uses`` (side arrays it takes when given, such as
    the recording's noise floor); the property ``report_maps`` (the score comes with
    maps worth drawing).
    """

    Config: ClassVar[type[DetectorConfig]] = DetectorConfig
    normalize: ClassVar[bool] = True
    fixed_length: ClassVar[bool] = True
    needs: ClassVar[tuple[str, ...]] = ()
    uses: ClassVar[tuple[str, ...]] = ()
    #: Config fields that change only how a fitted model scores, not what ``fit`` learns: a
    #: fitted detector switches them with :meth:`rescored` instead of being fitted again.
    scoring_fields: ClassVar[tuple[str, ...]] = ("contamination",)
    #: The values of the config's ``scoring`` field, for a detector that has one (the first is
    #: the default); :data:`GLR_SCORING` among them means the shared GLR scoring of its residual.
    scoring_modes: ClassVar[tuple[str, ...]] = ()
    registry_name: str = ""  # set by the registry (variants of one class differ here)

    @property
    def edge_guard(self) -> int:
        """Steps at each end of a window whose scores a stream of overlapping windows leaves to
        the windows that hold them further in (:class:`railwatch.detection.stream.
        StreamingDetector`): 0, every step counts."""
        return 0

    @classmethod
    def field_scale(cls, fs: float) -> dict[str, Any]:
        """Config defaults for recordings prepared at field scale at ``fs`` Hz (``railwatch
        train`` applies them under the user's own settings): none unless a detector's design
        is written in the benchmark's sample counts and needs more at a real rate."""
        return {}

    @property
    def report_maps(self) -> bool:
        """Whether ``score(X, extras=True)`` adds maps that show how the score was made, for a
        report to draw on example windows (the attention model scoring by its attention)."""
        return False

    def __init__(self, config: DetectorConfig | None = None, **overrides: Any) -> None:
        base = config if config is not None else self.Config()
        if not isinstance(base, self.Config):
            raise RailwatchError(f"{type(self).__name__} takes a {self.Config.__name__}")
        self.config = replace(base, **overrides) if overrides else base
        mode = getattr(self.config, "scoring", None)
        if self.scoring_modes and mode not in self.scoring_modes:
            raise RailwatchError(f"unknown scoring mode {mode!r} for {type(self).__name__}; "
                                 f"choose one of {', '.join(self.scoring_modes)}")

    # -- public API ----------------------------------------------------------------------
    def fit(self, X: Any, context: Mapping[str, Any] | None = None) -> Detector:
        """Learn from unlabelled windows ``X`` (N, T, C); returns ``self``."""
        X = check_windows(X)
        self.__dict__.pop("stats_", None)  # fitted again: what it was fitted with goes
        ctx = self._check_context(context, len(X))
        _, self.n_steps_, self.n_channels_ = X.shape
        self.stats_: dict[str, NDArray[Any]] = {}
        if self.uses:  # which optional side arrays it learned with: scoring must give the same
            self.stats_["uses"] = np.array([k in ctx for k in self.uses])
        if self.normalize:
            mean = X.mean(axis=(0, 1), dtype=np.float64)
            std = X.std(axis=(0, 1), dtype=np.float64)
            self.stats_["input_mean"] = mean.astype(np.float32)
            self.stats_["input_std"] = np.where(std > 1e-8, std, 1.0).astype(np.float32)
        self._fit(self.normalized(X), ctx)
        self._fit_threshold(self.normalized(X), ctx)
        return self

    def rescored(
        self, X: Any, context: Mapping[str, Any] | None = None, **changes: Any
    ) -> Detector:
        """A copy of this fitted detector with scoring-only settings (``scoring_fields``)
        changed; its threshold is fitted again on ``X``, the windows it was trained on.

        The network and statistics are shared, not copied: this is how one trained
        Attention-Focused Transformer gives its ``attention``, ``reconstruction`` and
        ``combined`` rows without being trained three times.
        """
        self._check_fitted()
        learned = sorted(set(changes) - set(self.scoring_fields))
        if learned:
            raise RailwatchError(
                f"{', '.join(learned)} change{'s' if len(learned) == 1 else ''} what "
                f"{type(self).__name__} learns: fit a new detector instead"
            )
        new = type(self)(config_from_dict(type(self.config), {**asdict(self.config), **changes}))
        new.__dict__.update({k: v for k, v in self.__dict__.items() if k != "config"})
        new.stats_ = dict(self.stats_)
        X = check_windows(X, n_channels=self.n_channels_,
                          n_steps=self.n_steps_ if self.fixed_length else None)
        new._fit_threshold(new.normalized(X), new._check_context(context, len(X)))
        return new

    def _fit_threshold(self, X: FloatArray, context: dict[str, FloatArray]) -> None:
        """``threshold_``: the ``1 − contamination`` quantile of the training instance scores."""
        self.decision_scores_ = self._score(X, context, extras=False).instance
        self.set_threshold(ContaminationQuantile(self.config.contamination))

    def set_threshold(self, rule: ThresholdRule) -> float:
        """Fit ``threshold_`` to the training instance scores (``decision_scores_``) by ``rule``
        (:mod:`railwatch.scoring.thresholds`), replacing the fitted one; returns it. It is stored
        once, with the fitted statistics."""
        self.threshold_ = rule.fit(self.decision_scores_)
        self.stats_["threshold"] = np.array(self.threshold_)
        return self.threshold_

    def score(
        self, X: Any, context: Mapping[str, Any] | None = None, extras: bool = False
    ) -> Scores:
        """Scores of windows ``X`` (N, T, C); ``extras=True`` adds large maps (attention, ...)."""
        self._check_fitted()
        X = check_windows(
            X, n_channels=self.n_channels_,
            n_steps=self.n_steps_ if self.fixed_length else None,
        )
        return self._score(self.normalized(X), self._check_context(context, len(X)), extras)

    def localize(self, X: Any, context: Mapping[str, Any] | None = None) -> Localization:
        """The most anomalous time step (index and seconds) and channel of each window."""
        scores = self.score(X, context)
        return localize(scores.point, scores.channel, self.config.fs)

    def predict(self, X: Any, context: Mapping[str, Any] | None = None) -> NDArray[np.int8]:
        """1 for windows whose instance score exceeds the fitted ``threshold_``, else 0."""
        return (self.score(X, context).instance > self.threshold_).astype(np.int8)

    # -- hooks ---------------------------------------------------------------------------
    @abstractmethod
    def _fit(self, X: FloatArray, context: dict[str, FloatArray]) -> None:
        """Learn weights and score statistics from normalised windows (store arrays in stats_)."""

    @abstractmethod
    def _score(self, X: FloatArray, context: dict[str, FloatArray], extras: bool) -> Scores:
        """Scores of normalised windows."""

    def _state_dict(self) -> dict[str, torch.Tensor] | None:
        """Network weights to save, if any."""
        return None

    def _load_state(self, state: dict[str, torch.Tensor] | None) -> None:
        """Rebuild the network from saved weights (after ``stats_`` and the shapes are set)."""
        return None

    # -- persistence ---------------------------------------------------------------------
    def save(self, path: str | os.PathLike[str],
             extra_files: Mapping[str, str] | None = None) -> Path:
        """Write the fitted detector into the model folder ``path``, replaced only when complete
        (:func:`railwatch.detectors.model_folder.write`). ``extra_files`` (name -> text) are
        written into the same folder in the same atomic step: for example the recording layout
        of a model trained on recordings."""
        self._check_fitted()
        header = {
            "detector": self.registry_name or type(self).__name__,
            "class": f"{type(self).__module__}.{type(self).__qualname__}",
            "config": asdict(self.config), "n_steps": self.n_steps_,
            "n_channels": self.n_channels_,
        }
        return model_folder.write(path, header, self.stats_, self._state_dict(), extra_files)

    @classmethod
    def _from_saved(cls, header: dict[str, Any], path: Path) -> Detector:
        """The detector saved in the model folder ``path`` whose checked header is ``header``."""
        return cls.restored(header["detector"], header["config"], header,
                            model_folder.read_stats(path), model_folder.HEADER,
                            lambda det: det._load_state(model_folder.read_weights(path)))

    @classmethod
    def restored(cls, name: str, config: Mapping[str, Any], shape: Mapping[str, Any],
                 stats: dict[str, NDArray[Any]], where: str,
                 attach: Callable[[Detector], None]) -> Detector:
        """A fitted detector rebuilt from a file, the one path for every file that holds one (a
        model folder, an ONNX export): its ``config`` values, ``n_steps`` and ``n_channels``
        from ``shape``, the fitted statistics, then ``attach`` gives it its network (the saved
        weights, an onnxruntime session); checked by :func:`verify_restored`. ``where`` names
        the part of the file the config came from, in errors."""
        try:
            values = config_from_dict(cls.Config, config)
        except RailwatchError as e:
            raise RailwatchError(f"{where}: the config does not fit {name} ({e})") from None
        det = cls(values)
        det.registry_name = name
        det.n_steps_, det.n_channels_ = (positive_count(shape, k, where)
                                         for k in ("n_steps", "n_channels"))
        det.stats_ = stats
        attach(det)
        verify_restored(det)
        return det

    # -- helpers -------------------------------------------------------------------------
    def normalized(self, X: FloatArray) -> FloatArray:
        """The windows as the detector's model sees them: standardised by the training windows'
        per-channel mean and std when the detector normalises (a public hook for research
        scripts that look inside a detector, such as benchmarks/)."""
        if not self.normalize:
            return X
        return (X - self.stats_["input_mean"]) / self.stats_["input_std"]

    def _check_fitted(self) -> None:
        if not hasattr(self, "stats_"):
            raise RailwatchError(
                f"{type(self).__name__} is not fitted yet: call fit(X) or load a saved model"
            )

    def fitted_uses(self) -> list[str]:
        """The optional side arrays (``uses``) this fitted detector learned with."""
        mask = self.stats_.get("uses", np.zeros(len(self.uses), bool))
        return [k for k, on in zip(self.uses, np.atleast_1d(mask), strict=False) if on]

    def _check_context(
        self, context: Mapping[str, Any] | None, n: int
    ) -> dict[str, FloatArray]:
        ctx = dict(context or {})
        missing = [k for k in self.needs if k not in ctx]
        if missing:
            raise RailwatchError(
                f"{self.registry_name or type(self).__name__} needs {', '.join(missing)} "
                "(synthetic data generated with --components)"
            )
        given = [k for k in self.uses if ctx.get(k) is not None]
        if hasattr(self, "stats_") and given != self.fitted_uses():
            learned = ", ".join(self.fitted_uses()) or "no side array"
            raise RailwatchError(
                f"{self.registry_name or type(self).__name__} was fitted with {learned} but is "
                f"scored with {', '.join(given) or 'none'}: score it as it was fitted (railwatch "
                "detect gives a model trained on recordings what it was trained with)")
        out = {}
        for k in (*self.needs, *given):
            arr = np.asarray(ctx[k], dtype=np.float32)
            if len(arr) != n:
                raise RailwatchError(f"{k} has {len(arr)} windows, X has {n}")
            out[k] = arr
        return out


def verify_restored(det: Detector) -> None:
    """Check a detector rebuilt from a file (a model folder, an ONNX export) before it is used.

    Sets ``threshold_`` from ``stats_``; checks the input normalisation's shape; then scores one
    window of zeros, so that a statistic missing from the file or of the wrong shape, or weights
    that do not fit, fail now, in one line, instead of in the middle of a recording. Raises
    :class:`RailwatchError` without naming the file (the caller adds it).
    """
    stats = det.stats_
    if "threshold" not in stats:
        raise RailwatchError("the fitted statistics lack the threshold")
    if np.size(stats["threshold"]) != 1 or stats["threshold"].dtype.kind not in "fiu":
        raise RailwatchError("the fitted threshold is not a number")
    det.threshold_ = float(stats["threshold"])
    if det.n_steps_ < 1 or det.n_channels_ < 1:
        raise RailwatchError(f"windows of {det.n_steps_} x {det.n_channels_} are impossible")
    if det.normalize:
        for key in ("input_mean", "input_std"):
            if key not in stats:
                raise RailwatchError(f"the fitted statistics lack {key}")
            if stats[key].shape != (det.n_channels_,):
                raise RailwatchError(
                    f"the fitted {key} has shape {stats[key].shape}, the model "
                    f"{_plural(det.n_channels_, 'channel')}")
    probe = np.zeros((1, det.n_steps_, det.n_channels_), dtype=np.float32)
    context = {k: np.ones_like(probe) for k in (*det.needs, *det.fitted_uses())}
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            scores = det.score(probe, context)
        if scores.instance.shape != (1,) or scores.channel.shape != probe.shape:
            raise ValueError(f"scores of shape {scores.channel.shape} for windows {probe.shape}")
    except RailwatchError:
        raise
    except Exception as e:  # noqa: BLE001 - whatever breaks, the saved model is damaged
        raise RailwatchError(f"the saved model does not score a window ({type(e).__name__}: "
                             f"{one_line(e)[:160]}): it is damaged or was edited") from None


def positive_count(values: Mapping[str, Any], key: str, where: str) -> int:
    """``values[key]`` as a count of steps or channels: a whole number of at least 1."""
    value = values[key]
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise RailwatchError(f"{where}: {key} must be a positive whole number, got {value!r}")
    return value


def standardize(values: NDArray[Any], mean: NDArray[Any], std: NDArray[Any]) -> NDArray[Any]:
    """``(values − mean) / std`` with a floor on std, for per-channel score standardisation."""
    return (values - mean) / np.maximum(std, 1e-8)


def peak_statistics(raw: NDArray[Any]) -> dict[str, NDArray[np.float32]]:
    """``score_median`` and ``score_scale`` (C,) of raw channel scores (N, T, C) of the training
    windows: per channel, the median and the MAD-based scale (1.4826 MAD; 1 where it vanishes)
    of each window's largest score. Robust: the training set holds 10 % anomalies, whose huge
    scores would inflate a mean and std."""
    peak = raw.max(axis=1)  # (N, C): each window's largest score per channel
    median = np.median(peak, axis=0)
    mad = MAD_TO_STD * np.median(np.abs(peak - median), axis=0)
    return {"score_median": median.astype(np.float32),
            "score_scale": np.where(mad > 1e-8, mad, 1.0).astype(np.float32)}


def peak_standardized(raw: NDArray[Any], stats: Mapping[str, NDArray[Any]]) -> Scores:
    """Scores of raw channel scores (N, T, C) standardised by :func:`peak_statistics`: channel
    = standardised score, point = max over channels, instance = max over time."""
    channel = standardize(raw, stats["score_median"], stats["score_scale"]).astype(np.float32)
    point = reduce_point_max(channel)
    return Scores(instance=reduce_instance_max(point), point=point, channel=channel)
