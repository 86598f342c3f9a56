"""The window file: one ``.npz`` holding windows ``X`` (n_windows, n_steps, n_channels) float32,
optionally with the benchmark's labels, its sampled parameters and its components. What the
generator writes, what the detectors read and what ``evaluate`` scores, whatever produced the
windows; plain ``numpy.load`` reads it too (``meta`` is a JSON string).

Keys: ``X``; labels ``y`` (n,) 0/1, ``mask`` (n, T, C) true where an anomaly was added, ``kind``
(n,) :data:`NORMAL` / :data:`SPIKE` / :data:`LOCAL`, ``channel`` (n,) the anomalous channel or
−1; components ``nuisance`` and ``noise_std`` (n, T, C), the signal without noise and anomaly and
the per-sample noise std (what the oracle needs); every sampled parameter as ``param_<name>``;
``meta``.
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.atomic import atomic_savez
from railwatch.errors import RailwatchError

#: The anomaly kinds of ``kind``.
NORMAL, SPIKE, LOCAL = 0, 1, 2
KIND_NAMES = {NORMAL: "normal", SPIKE: "spike", LOCAL: "local deviation"}

LABEL_KEYS = ("y", "mask", "kind", "channel")
COMPONENT_KEYS = ("nuisance", "noise_std")
PARAM_PREFIX = "param_"


@dataclass
class WindowSet:
    """Windows (arrays batch-first, times in seconds) with whatever labels and components the
    file holds; a generated benchmark set has all of them."""

    X: NDArray[np.float32]  # (n, T, C)
    y: NDArray[np.int8] | None = None  # (n,)
    mask: NDArray[np.bool_] | None = None  # (n, T, C)
    kind: NDArray[np.int8] | None = None  # (n,) 0 normal, 1 spike, 2 local
    channel: NDArray[np.int16] | None = None  # (n,) anomalous channel or -1
    params: dict[str, NDArray[np.float64]] = field(default_factory=dict)  # name -> (n, C) or (n,)
    meta: dict[str, Any] = field(default_factory=dict)
    nuisance: NDArray[np.float32] | None = None  # (n, T, C) signal without noise and anomaly
    noise_std: NDArray[np.float32] | None = None  # (n, T, C)
    extras: dict[str, NDArray[Any]] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.X.shape[0])

    @property
    def components(self) -> dict[str, NDArray[Any]]:
        """The components the file holds, by name (what ``fit``/``score`` take as side arrays)."""
        return {k: getattr(self, k) for k in COMPONENT_KEYS if getattr(self, k) is not None}

    def require_labels(self, path: str | os.PathLike[str],
                       keys: tuple[str, ...] = ("y", "mask", "channel")) -> None:
        """One-line error unless the windows carry the labels ``keys`` (by default those
        evaluation needs)."""
        missing = [k for k in keys if getattr(self, k) is None]
        if missing:
            raise RailwatchError(f"{path} has no labels ({', '.join(missing)}): evaluation needs "
                                 "a labelled set such as one from 'railwatch generate'")

    def labels(self, path: str | os.PathLike[str] = "the windows") -> tuple[
            NDArray[np.int8], NDArray[np.bool_], NDArray[np.int8], NDArray[np.int16]]:
        """``y``, ``mask``, ``kind`` and ``channel``; a one-line error where one is missing."""
        self.require_labels(path, ("y", "mask", "kind", "channel"))
        assert self.y is not None and self.mask is not None  # narrowed for the type checker
        assert self.kind is not None and self.channel is not None
        return self.y, self.mask, self.kind, self.channel

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write one ``.npz`` atomically (temporary file, then rename): nothing partial is left."""
        arrays: dict[str, Any] = {"X": self.X}
        arrays.update({k: getattr(self, k) for k in LABEL_KEYS if getattr(self, k) is not None})
        arrays["meta"] = np.array(json.dumps(self.meta))
        arrays.update({PARAM_PREFIX + k: v for k, v in self.params.items()})
        arrays.update(self.components)
        return atomic_savez(path, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> WindowSet:
        """Read a window file, with one-line errors for a missing, foreign or malformed file."""
        path = Path(path)
        if not path.is_file():
            raise RailwatchError(f"no such file: {path}")
        try:
            with np.load(path, allow_pickle=False) as f:
                if "X" not in f.files:
                    raise RailwatchError(f"{path} has no array 'X' (windows of shape "
                                         "(n_windows, n_steps, n_channels)); it holds: "
                                         f"{', '.join(f.files) or 'nothing'}")
                optional = {k: f[k] for k in (*LABEL_KEYS, *COMPONENT_KEYS) if k in f.files}
                return cls(
                    X=f["X"], **optional,
                    params={k[len(PARAM_PREFIX):]: f[k] for k in f.files
                            if k.startswith(PARAM_PREFIX)},
                    meta=json.loads(str(f["meta"])) if "meta" in f.files else {},
                )
        except RailwatchError:
            raise
        except (OSError, ValueError, zipfile.BadZipFile, json.JSONDecodeError) as e:
            raise RailwatchError(f"cannot read {path} as an .npz window file: "
                                 f"{' '.join(str(e).split())[:160]}") from None


def load_windows(path: str | os.PathLike[str]) -> WindowSet:
    """Read a window file (:meth:`WindowSet.load`)."""
    return WindowSet.load(path)
