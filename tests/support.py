"""Helpers shared by the tests (on the import path through pyproject's pytest `pythonpath`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import yaml

from railwatch.trackmap import PROFILE_KIND

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


# ------------------------------------------------------------ scan folders for the track map
def profiles(n: int, defects: np.ndarray, seen: list[int] | None = None, bump: float = 1.5,
             loud: tuple[float, float] | None = None, seed: int = 0,
             length: float = 5_000.0,
             ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Score profiles of ``n`` passes sampled every 0.25 m (exponential noise, 0.3 m of
    position jitter per pass): each defect adds ``bump`` times the noise scale on the passes
    in ``seen`` (all by default), a loud stretch triples every pass's scores."""
    rng = np.random.default_rng(seed)
    xs, scores = [], []
    for i in range(n):
        x = np.arange(0, length, 0.25) + rng.uniform(0, 0.25)
        s = rng.exponential(size=len(x))
        if seen is None or i in seen:
            for d in defects:
                near = np.abs(x - d - rng.normal(0, 0.3)) <= 0.4
                s[near] += bump * rng.exponential(size=near.sum()) + bump
        if loud is not None:
            s[(x >= loud[0]) & (x <= loud[1])] *= 3.0
        xs.append(x)
        scores.append(s)
    return xs, scores


def write_pass(folder: Path, name: str, x: np.ndarray, time_s: np.ndarray,
               channel_score: np.ndarray, channels: tuple[str, ...], groups: tuple[str, ...],
               defects: np.ndarray, route: np.ndarray | None = None,
               weld: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """One recording of a scan folder as ``railwatch scan`` writes it: its stretch, an event
    at each defect (the highest channel's score there), its score profile (and its GNSS
    ``route``: (k, 3) time, latitude, longitude; its weld test: positions and z (k, 2))."""
    (folder / f"{name}.scan.json").write_text(json.dumps(
        {"position_first_m": float(x[0]), "position_last_m": float(x[-1]),
         "profile": PROFILE_KIND}))
    rows = ["start_s,end_s,peak_s,channel,group,score,threshold,position_m"]
    for d in defects:
        j = int(np.argmin(np.abs(x - d)))
        rows.append(f"1.0,1.1,1.05,axle_1,axle,{channel_score[j].max():.3f},3.0,{x[j]:.3f}")
    (folder / f"{name}.events.csv").write_text("\n".join(rows) + "\n")
    extra = {} if route is None else {"route": route}
    if weld is not None:
        extra.update(weld_position_m=weld[0], weld_z=weld[1].astype(np.float32))
    np.savez(folder / f"{name}.profile.npz", time_s=time_s, position_m=x,
             channel_score=channel_score.astype(np.float32), channels=np.array(channels),
             groups=np.array(groups), **extra)


def scan_folder(folder: Path, xs: list[np.ndarray], scores: list[np.ndarray],
                defects: np.ndarray, located: bool = False) -> None:
    """A scan folder of passes whose scores ``scores[i]`` are axle_1's (axle_2 has half of
    them, body_1 none), each run at 20 m/s; ``located``: with its GNSS route, exact fixes on
    the line of :func:`railwatch.physics.gnss.line` (-500 to 20,000 m, seed 0) at 10 Hz."""
    for i, (x, s) in enumerate(zip(xs, scores, strict=True)):
        route = None
        if located:
            from railwatch.physics import gnss

            line = gnss.line(-500.0, 20_000.0, 0)
            t = np.arange(0.0, float(x[-1] / 20.0), 0.1)
            lat, lon = gnss.to_degrees(np.interp(t * 20.0, line[0], line[1]),
                                       np.interp(t * 20.0, line[0], line[2]))
            route = np.stack([t, lat, lon], axis=1)
        write_pass(folder, f"pass{i:02d}", x, x / 20.0,
                   np.stack([s, 0.5 * s, np.zeros_like(s)], axis=1),
                   ("axle_1", "axle_2", "body_1"), ("axle", "axle", "body"), defects, route)
