"""Window files: any ``.npz`` holding ``X`` (n_windows, n_steps, n_channels), optionally with the
benchmark's labels and components. What the detectors read, whatever produced the windows."""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.errors import RailwatchError

LABEL_KEYS = ("y", "mask", "kind", "channel")
COMPONENT_KEYS = ("nuisance", "noise_std")


@dataclass
class WindowFile:
    X: NDArray[np.float32]
    labels: dict[str, NDArray[Any]] = field(default_factory=dict)  # y, mask, kind, channel
    components: dict[str, NDArray[Any]] = field(default_factory=dict)  # nuisance, noise_std
    meta: dict[str, Any] = field(default_factory=dict)

    def require_labels(self, path: str | os.PathLike[str]) -> None:
        missing = [k for k in ("y", "mask", "channel") if k not in self.labels]
        if missing:
            raise RailwatchError(f"{path} has no labels ({', '.join(missing)}): evaluation needs "
                                 "a labelled set such as one from 'railwatch generate'")


def load_windows(path: str | os.PathLike[str]) -> WindowFile:
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
            meta = json.loads(str(f["meta"])) if "meta" in f.files else {}
            return WindowFile(
                X=f["X"], labels={k: f[k] for k in LABEL_KEYS if k in f.files},
                components={k: f[k] for k in COMPONENT_KEYS if k in f.files}, meta=meta,
            )
    except RailwatchError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, json.JSONDecodeError) as e:
        raise RailwatchError(f"cannot read {path} as an .npz window file: "
                             f"{' '.join(str(e).split())[:160]}") from None
