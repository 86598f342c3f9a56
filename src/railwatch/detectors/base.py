"""The detector API shared by every model, and the training loop of the deep ones.

Contract (``spec/detectors.md``, "Common API"), in the style of scikit-learn and PyOD:

- ``fit(X) -> self`` learns everything: per-channel input normalisation, weights, score
  statistics and ``threshold_``, the ``1 − contamination`` quantile of the training instance scores.
  Learned state ends in ``_``; nothing happens in ``__init__`` but storing the config.
- ``score(X) -> Scores`` with ``instance`` (N,), ``point`` (N, T) and ``channel`` (N, T, C);
  higher is more anomalous.
- ``localize``, ``predict``, ``save``/``load`` (weights as ``state_dict``, config as JSON, fitted
  arrays as ``.npz``; no pickled objects).

Deep detectors subclass :class:`TorchDetector`, which owns the device, seeding, batching, the
validation split carved from the training set, early stopping and progress; each model supplies
small hooks.
"""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import warnings
from abc import ABC, abstractmethod
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from numpy.typing import NDArray

from railwatch.atomic import fsync_path, sha256_file
from railwatch.errors import RailwatchError, naming, one_line
from railwatch.progress import Progress

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float32]
FORMAT = "railwatch-detector"
#: The ``scoring`` mode that scores a model's residual by the shared GLR scan.
GLR_SCORING = "glr"
FORMAT_VERSION = 1


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
            items = value.split(",") if isinstance(value, str) else list(value)
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


@dataclass(frozen=True)
class Localization:
    """The most anomalous time step and channel of each window."""

    time_index: NDArray[np.int64]  # (N,)
    time_s: NDArray[np.float64]  # (N,) seconds from the window start
    channel: NDArray[np.int64]  # (N,)


def reduce_point_max(channel: FloatArray) -> FloatArray:
    """Default point reduction: ``point = max over channels of channel`` (N, T, C) -> (N, T)."""
    return channel.max(axis=2)


def reduce_instance_max(point: FloatArray) -> FloatArray:
    """Default instance reduction: ``instance = max over time of point`` (N, T) -> (N,)."""
    return point.max(axis=1)


def localize_scores(scores: Scores, fs: float) -> Localization:
    """Time index = argmax of ``point``; channel = argmax of ``channel`` at that time."""
    t = scores.point.argmax(axis=1)
    c = scores.channel[np.arange(len(t)), t].argmax(axis=1)
    return Localization(time_index=t.astype(np.int64), time_s=t / fs, channel=c.astype(np.int64))


# ----------------------------------------------------------------------------- detectors
class Detector(ABC):
    """Base of every detector. Subclasses implement :meth:`_fit` and :meth:`_score`.

    Class attributes a subclass may set:
    ``Config`` (its config dataclass), ``normalize`` (per-channel standardisation of inputs from
    training statistics, default on), ``fixed_length`` (scoring needs the fitted window length),
    ``needs`` (names of side arrays, e.g. the oracle's generator components, that ``fit`` and
    ``score`` must receive in ``context``).
    """

    Config: ClassVar[type[DetectorConfig]] = DetectorConfig
    normalize: ClassVar[bool] = True
    fixed_length: ClassVar[bool] = True
    needs: ClassVar[tuple[str, ...]] = ()
    #: Config fields that change only how a fitted model scores, not what ``fit`` learns: a
    #: fitted detector switches them with :meth:`rescored` instead of being fitted again.
    scoring_fields: ClassVar[tuple[str, ...]] = ("contamination",)
    #: The values of the config's ``scoring`` field, for a detector that has one (the first is
    #: the default); :data:`GLR_SCORING` among them means the shared GLR scoring of its residual.
    scoring_modes: ClassVar[tuple[str, ...]] = ()
    registry_name: str = ""  # set by the registry (variants of one class differ here)

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
        ctx = self._check_context(context, len(X))
        _, self.n_steps_, self.n_channels_ = X.shape
        self.stats_: dict[str, NDArray[Any]] = {}
        if self.normalize:
            mean = X.mean(axis=(0, 1), dtype=np.float64)
            std = X.std(axis=(0, 1), dtype=np.float64)
            self.stats_["input_mean"] = mean.astype(np.float32)
            self.stats_["input_std"] = np.where(std > 1e-8, std, 1.0).astype(np.float32)
        self._fit(self._normalized(X), ctx)
        self._fit_threshold(self._normalized(X), ctx)
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
        new._fit_threshold(new._normalized(X), new._check_context(context, len(X)))
        return new

    def _fit_threshold(self, X: FloatArray, context: dict[str, FloatArray]) -> None:
        """``threshold_``: the ``1 − contamination`` quantile of the training instance scores."""
        self.decision_scores_ = self._score(X, context, extras=False).instance
        self.threshold_ = float(np.quantile(self.decision_scores_, 1.0 - self.config.contamination))
        self.stats_["threshold"] = np.array(self.threshold_)

    def score(
        self, X: Any, context: Mapping[str, Any] | None = None, extras: bool = False
    ) -> Scores:
        """Scores of windows ``X`` (N, T, C); ``extras=True`` adds large maps (attention, ...)."""
        self._check_fitted()
        X = check_windows(
            X, n_channels=self.n_channels_,
            n_steps=self.n_steps_ if self.fixed_length else None,
        )
        return self._score(self._normalized(X), self._check_context(context, len(X)), extras)

    def localize(self, X: Any, context: Mapping[str, Any] | None = None) -> Localization:
        """The most anomalous time step (index and seconds) and channel of each window."""
        return localize_scores(self.score(X, context), self.config.fs)

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
        """Write the fitted detector into the directory ``path`` (replaced only when complete).

        ``extra_files`` (name -> text) are written into the same directory, in the same atomic
        step: for example the recording layout of a model trained on recordings.

        The folder is written as ``.NAME.tmp-PID`` beside ``path``, every file and the folder
        flushed to disk (``fsync``), then swapped in: the old model, if any, is renamed to
        ``.NAME.old-PID``, the new one to ``path``, the old one deleted. A process killed at
        any point (or a power cut, as far as the file system keeps its ``fsync`` promises)
        leaves the old model or the new one at ``path``; killed between the two renames, it
        leaves no ``path`` but the previous model in ``.NAME.old-PID``, which
        :func:`load_detector` points to. Leftovers of writers that are no longer running are
        removed by the next save. ``detector.json`` records the SHA-256 of every other file,
        so that a damaged or replaced file is refused when the model is loaded.
        """
        self._check_fitted()
        path = Path(path)
        if path.exists() and not (path / "detector.json").is_file() and any(path.iterdir()):
            raise RailwatchError(
                f"{path} exists and is not a railwatch model directory: choose a new folder"
            )
        if not path.parent.is_dir():
            raise RailwatchError(f"cannot write {path}: folder {path.parent} does not exist")
        for stale in _stale_siblings(path, "tmp"):  # half-written by a killed save
            shutil.rmtree(stale, ignore_errors=True)
        tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
        old = path.with_name(f".{path.name}.old-{os.getpid()}")
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        moved = False
        try:
            for name, text in (extra_files or {}).items():
                if name in _MODEL_FILES or Path(name).name != name or name.startswith("."):
                    raise RailwatchError(f"cannot save an extra file named {name!r}")
                (tmp / name).write_text(text)
            np.savez(tmp / "stats.npz", **self.stats_)  # type: ignore[arg-type]
            state = self._state_dict()
            if state is not None:
                torch.save(state, tmp / "weights.pt")
            header = {
                "format": FORMAT, "format_version": FORMAT_VERSION,
                "detector": self.registry_name or type(self).__name__,
                "class": f"{type(self).__module__}.{type(self).__qualname__}",
                "config": asdict(self.config), "n_steps": self.n_steps_,
                "n_channels": self.n_channels_,
                CHECKSUMS: {p.name: sha256_file(p) for p in sorted(tmp.iterdir())},
            }
            (tmp / "detector.json").write_text(json.dumps(header, indent=2))
            for p in tmp.iterdir():
                fsync_path(p)
            fsync_path(tmp)
            if path.exists():
                shutil.rmtree(old, ignore_errors=True)  # a dead namesake's, not ours
                os.rename(path, old)
                moved = True
            os.rename(tmp, path)
            moved = False
            fsync_path(path.parent)
        except BaseException:
            if moved and not path.exists():
                os.rename(old, path)  # put the old model back
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        shutil.rmtree(old, ignore_errors=True)
        for stale in _stale_siblings(path, "old"):  # a previous model a killed save set aside
            shutil.rmtree(stale, ignore_errors=True)
        return path

    @classmethod
    def _from_saved(cls, header: dict[str, Any], path: Path) -> Detector:
        """The detector saved in ``path`` whose ``detector.json`` is ``header`` (checked)."""
        name = header["detector"]
        try:
            config = config_from_dict(cls.Config, header["config"])
        except RailwatchError as e:
            raise RailwatchError(f"detector.json: the config does not fit {name} ({e})") from None
        det = cls(config)
        det.n_steps_, det.n_channels_ = (positive_count(header, k, "detector.json")
                                      for k in ("n_steps", "n_channels"))
        if not (path / "stats.npz").is_file():
            raise RailwatchError("stats.npz is missing")
        try:
            with np.load(path / "stats.npz", allow_pickle=False) as f:
                det.stats_ = {k: f[k] for k in f.files}
        except Exception as e:  # noqa: BLE001 - zip, npy or pickle errors alike
            raise RailwatchError(f"stats.npz is damaged ({type(e).__name__}: "
                                 f"{one_line(e)[:120]})") from None
        weights = path / "weights.pt"
        state = None
        if weights.exists():
            try:
                state = torch.load(weights, map_location="cpu", weights_only=True)
            except Exception as e:  # noqa: BLE001 - torch's message is about pickle safety
                raise RailwatchError(f"weights.pt is damaged or holds no network weights "
                                     f"({type(e).__name__})") from None
        det._load_state(state)
        verify_restored(det)
        return det

    # -- helpers -------------------------------------------------------------------------
    def _normalized(self, X: FloatArray) -> FloatArray:
        if not self.normalize:
            return X
        return (X - self.stats_["input_mean"]) / self.stats_["input_std"]

    def _check_fitted(self) -> None:
        if not hasattr(self, "stats_"):
            raise RailwatchError(
                f"{type(self).__name__} is not fitted yet: call fit(X) or load a saved model"
            )

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
        out = {}
        for k in self.needs:
            arr = np.asarray(ctx[k], dtype=np.float32)
            if len(arr) != n:
                raise RailwatchError(f"{k} has {len(arr)} windows, X has {n}")
            out[k] = arr
        return out


def load_detector(path: str | os.PathLike[str]) -> Detector:
    """Load a detector saved with :meth:`Detector.save`; any detector class, by its header.

    Every way a model folder can be damaged (a file missing, truncated, replaced or edited; a
    header naming another detector, a newer format or settings this version does not know) is
    a one-line :class:`RailwatchError` naming the folder; the loaded detector has scored a
    window, so that it does not fail later, in the middle of a recording.
    """
    from railwatch.detectors.registry import class_for

    path = Path(path)
    if not path.is_dir():
        previous = [p for p in _stale_siblings(path, "old") if (p / "detector.json").is_file()]
        if previous:
            raise RailwatchError(
                f"no model directory at {path}; a save that was interrupted left the previous "
                f"model in {previous[-1]}: rename it to {path.name} to use it, or train again")
        raise RailwatchError(f"no model directory at {path}")
    if not (path / "detector.json").is_file():
        raise RailwatchError(f"{path} is not a railwatch model directory (no detector.json): "
                             "give the folder written by 'railwatch train'")
    try:
        header = json.loads((path / "detector.json").read_text())
        if not isinstance(header, dict) or header.get("format") != FORMAT:
            raise ValueError("detector.json is not a railwatch model header")
        version = header.get("format_version", 0)
        if not isinstance(version, int) or isinstance(version, bool):
            raise ValueError(f"detector.json: format_version {version!r} is not a number")
        if version > FORMAT_VERSION:
            raise RailwatchError(
                f"{path} was saved by a newer railwatch (format {version}, this one reads up "
                f"to {FORMAT_VERSION}): upgrade railwatch"
            )
        _verify_checksums(path, header)
        cls = class_for(header["detector"])
        det = cls._from_saved(header, path)
        det.registry_name = header["detector"]
        return det
    except RailwatchError as e:
        raise naming(str(path), e) from None
    except Exception as e:  # noqa: BLE001 - any failure to read a saved model is the same to the user
        raise RailwatchError(
            f"{path} is not a readable railwatch model directory ({type(e).__name__}: "
            f"{one_line(e)[:200]})"
        ) from None


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
    context = {k: np.ones_like(probe) for k in det.needs}
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


#: The files :meth:`Detector.save` writes itself (extra files are named by the caller).
_MODEL_FILES = ("detector.json", "stats.npz", "weights.pt")
#: ``detector.json`` key of the SHA-256 of every other file in the folder.
CHECKSUMS = "sha256"


def _verify_checksums(path: Path, header: dict[str, Any]) -> None:
    """Every file listed in ``detector.json`` present and unchanged (models saved before
    checksums were recorded list none)."""
    sums = header.get(CHECKSUMS)
    if sums is None:
        return
    if not isinstance(sums, dict):
        raise ValueError(f"detector.json: {CHECKSUMS} is not a table of files")
    for name, digest in sums.items():
        if Path(name).name != name or name in ("", ".", ".."):
            raise ValueError(f"detector.json lists a file outside the folder: {name!r}")
        if not (path / name).is_file():
            raise RailwatchError(f"{path} is not a complete railwatch model: {name} is missing")
        if sha256_file(path / name) != digest:
            raise RailwatchError(
                f"{path} is not a readable railwatch model directory: {name} is damaged or was "
                "replaced (its SHA-256 differs from the one saved in detector.json): train the "
                "model again or restore the folder from a copy")


def _stale_siblings(path: Path, kind: str) -> list[Path]:
    """``.NAME.<kind>-PID`` folders beside ``path`` left by saves whose process is gone."""
    prefix = f".{path.name}.{kind}-"
    try:
        siblings = sorted(path.parent.iterdir())
    except OSError:
        return []
    found = []
    for p in siblings:
        pid = p.name[len(prefix):]
        if p.name.startswith(prefix) and pid.isdigit() and p.is_dir() and not p.is_symlink() \
                and int(pid) != os.getpid() and not _running(int(pid)):
            found.append(p)
    return found


def _running(pid: int) -> bool:
    """Whether process ``pid`` may still be running (when unsure: yes)."""
    if os.name != "posix":
        return True  # os.kill(pid, 0) would terminate it on Windows
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OSError, OverflowError):  # PermissionError: alive, another user's
        return True
    return True


def positive_count(values: Mapping[str, Any], key: str, where: str) -> int:
    """``values[key]`` as a count of steps or channels: a whole number of at least 1."""
    value = values[key]
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise RailwatchError(f"{where}: {key} must be a positive whole number, got {value!r}")
    return value


# ----------------------------------------------------------------------------- deep models
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
        self.fit_statistics(self._raw_all(val))

    @torch.no_grad()
    def _evaluate(self, X: FloatArray) -> float:
        self.model_.eval()
        total, count = 0.0, 0
        for i in range(0, len(X), 256):
            xb = torch.from_numpy(X[i:i + 256]).to(self.device_)
            total += self.validation_loss(xb) * len(xb)
            count += len(xb)
        return total / max(count, 1)

    #: Set on a detector loaded from ONNX: runs the network instead of ``model_`` (a callable
    #: from a normalised batch (B, T, C) to the raw outputs as arrays).
    backend_: Any = None

    @torch.no_grad()
    def _raw_all(self, X: FloatArray) -> dict[str, NDArray[Any]]:
        """Raw outputs of all windows, in batches of ``batch_size``."""
        if self.backend_ is None:
            self.model_.eval()
        parts: dict[str, list[NDArray[Any]]] = {}
        for i in range(0, len(X), self.config.batch_size):
            batch = np.ascontiguousarray(X[i:i + self.config.batch_size])
            if self.backend_ is not None:
                out = self.backend_(batch)
            else:
                out = {k: v.float().cpu().numpy()
                       for k, v in self.raw(torch.from_numpy(batch).to(self.device_)).items()}
            for k, v in out.items():
                parts.setdefault(k, []).append(v)
        return {k: np.concatenate(v) for k, v in parts.items()}

    def _score(self, X: FloatArray, context: dict[str, FloatArray], extras: bool) -> Scores:
        raw = self._raw_all(X)
        if getattr(self.config, "scoring", None) == GLR_SCORING:
            return self.glr_scores(raw, X.shape[1], extras)
        return self.scores_from_raw(raw, extras)

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
        from railwatch.scoring.residual import ResidualGLR

        channel = ResidualGLR(seed=self.config.seed).sample_scores(
            raw["residual"], self.residual_stride(), n_steps)
        point = reduce_point_max(channel)
        return Scores(instance=reduce_instance_max(point), point=point, channel=channel,
                      extras={"residual": raw["residual"]} if extras else {})

    def _state_dict(self) -> dict[str, torch.Tensor]:
        return {k: v.detach().cpu() for k, v in self.model_.state_dict().items()}

    def _load_state(self, state: dict[str, torch.Tensor] | None) -> None:
        if state is None:
            raise RailwatchError("the model directory has no weights.pt")
        if not isinstance(state, Mapping) or not all(
                isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()):
            raise RailwatchError("weights.pt does not hold network weights (a state_dict)")
        self.device_ = resolve_device(self.config.device)
        with seeded(self.config.seed):
            self.model_ = self.build(self.n_steps_, self.n_channels_)
        try:
            self.model_.load_state_dict(state)
        except RuntimeError as e:
            raise RailwatchError(f"weights.pt does not fit the {type(self).__name__} network of "
                                 f"this config: {one_line(e)[:200]}") from None
        self.model_.to(self.device_).eval()


def standardize(values: NDArray[Any], mean: NDArray[Any], std: NDArray[Any]) -> NDArray[Any]:
    """``(values − mean) / std`` with a floor on std, for per-channel score standardisation."""
    return (values - mean) / np.maximum(std, 1e-8)
