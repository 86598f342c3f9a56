"""Helpers shared by the tests (on the import path through pyproject's pytest `pythonpath`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py
import numpy as np
import yaml

TINY = Path(__file__).parents[1] / "configs" / "tiny"


def tiny_config(name: str) -> dict[str, Any]:
    """The tiny config of a detector (configs/tiny/NAME.yaml), silent: trains in seconds."""
    path = TINY / f"{name}.yaml"
    values = yaml.safe_load(path.read_text()) if path.exists() else {}
    return {**(values or {}), "progress": False}


def write_mat73(path: Path, cols: dict[str, np.ndarray]) -> None:
    """A MATLAB v7.3 file: HDF5 behind a 512-byte MATLAB header, vectors stored as (1, n)."""
    with h5py.File(path, "w", userblock_size=512) as f:
        for k, v in cols.items():
            f.create_dataset(k, data=np.asarray(v)[None, :])
    with open(path, "r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: x HDF5 schema 1.00 .".ljust(
            116) + b"\0" * 8 + b"\x00\x02IM")


def brute_family_max(g: np.ndarray, lengths: tuple[int, ...]) -> np.ndarray:
    """Loop over every window, channel, sample and covering box: max |sum| / √L."""
    n, t_len, c = g.shape
    out = np.full(g.shape, -np.inf)
    for i in range(n):
        for ch in range(c):
            for t in range(t_len):
                for L in lengths:
                    for s in range(max(0, t - L + 1), min(t, t_len - L) + 1):
                        z = abs(g[i, s:s + L, ch].sum()) / np.sqrt(L)
                        out[i, t, ch] = max(out[i, t, ch], z)
    return out


def rough_patches(windows: np.ndarray, seed: int = 0) -> np.ndarray:
    """``windows`` with a rough patch on channel 0: 0.3-1 s (30-100 samples at 100 Hz) of extra
    broadband vibration (N(0, 1)), as a pothole or a corrugated stretch gives. It makes the window
    louder without a spike or a box: a detector must score it above the quiet windows, which a
    per-window normalisation would hide (the loud-window tests)."""
    rng = np.random.default_rng(seed)
    rough = windows.copy()
    for w in rough:
        length = int(rng.integers(30, 101))
        start = int(rng.integers(0, w.shape[0] - length))
        w[start:start + length, 0] += rng.normal(0.0, 1.0, length)
    return rough
