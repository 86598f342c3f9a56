"""Generate, save and load labelled benchmark sets.

A set is windows ``X`` (n, T, C) float32 with their labels, every sampled parameter and a ``meta``
record. On disk it is one ``.npz`` that plain ``numpy.load`` reads (``meta`` is a JSON string).
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.atomic import atomic_path
from railwatch.progress import Progress
from railwatch.synthetic import components as comp
from railwatch.synthetic.anomalies import Anomalies, sample_anomalies
from railwatch.synthetic.stages import (
    BASE_VARS,
    BURST_VARS,
    IMPULSE_VARS,
    NOISE_CHANGE_VARS,
    PHASE_VARS,
    SPEC_VERSION,
    SPEED_VARS,
    StageConfig,
    draw_uniform,
    stage,
)

#: Named seed streams, split from one SeedSequence. The index of a name never changes, so that
#: adding a component to a stage leaves every other component's draws untouched.
STREAMS = ("base", "phase", "speed", "noise_change", "noise", "bursts", "impulses", "anomalies")

#: Instances rendered at once: bounds memory at a few (chunk, T, C) float64 arrays.
CHUNK = 512

PARAM_PREFIX = "param_"
LABEL_KEYS = ("anomaly_start", "anomaly_duration", "anomaly_offset")


def stream_seed(seed: int, name: str, *sub: int) -> np.random.SeedSequence:
    """The seed of stream ``name`` (optionally of its sub-stream ``sub``), split from ``seed``.

    Equal to ``SeedSequence(seed).spawn(len(STREAMS))[STREAMS.index(name)]`` (then ``.spawn`` for
    each ``sub``), built directly so that no spawn counter is shared.
    """
    return np.random.SeedSequence(seed, spawn_key=(STREAMS.index(name), *sub))


def streams(seed: int) -> dict[str, np.random.Generator]:
    """One independent generator per named stream, all split from ``SeedSequence(seed)``."""
    return {name: np.random.default_rng(stream_seed(seed, name)) for name in STREAMS}


@dataclass
class SyntheticSet:
    """A generated benchmark set (arrays batch-first, times in seconds)."""

    X: NDArray[np.float32]  # (n, T, C)
    y: NDArray[np.int8]  # (n,)
    mask: NDArray[np.bool_]  # (n, T, C)
    kind: NDArray[np.int8]  # (n,) 0 normal, 1 spike, 2 local
    channel: NDArray[np.int16]  # (n,) anomalous channel or -1
    params: dict[str, NDArray[np.float64]]  # name -> (n, C) per-channel or (n,) anomaly variables
    meta: dict[str, Any]
    nuisance: NDArray[np.float32] | None = None  # (n, T, C) signal without noise and anomaly
    noise_std: NDArray[np.float32] | None = None  # (n, T, C)
    extras: dict[str, NDArray[Any]] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.X.shape[0])

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write one ``.npz`` atomically (temporary file, then rename): nothing partial is left."""
        arrays: dict[str, Any] = {
            "X": self.X, "y": self.y, "mask": self.mask, "kind": self.kind, "channel": self.channel,
            "meta": np.array(json.dumps(self.meta)),
        }
        arrays.update({PARAM_PREFIX + k: v for k, v in self.params.items()})
        if self.nuisance is not None:
            arrays["nuisance"] = self.nuisance
        if self.noise_std is not None:
            arrays["noise_std"] = self.noise_std
        return atomic_savez(path, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> SyntheticSet:
        """Read a set written by :meth:`save`."""
        with np.load(path, allow_pickle=False) as f:
            meta = json.loads(str(f["meta"]))
            params = {k[len(PARAM_PREFIX):]: f[k] for k in f.files if k.startswith(PARAM_PREFIX)}
            return cls(
                X=f["X"], y=f["y"], mask=f["mask"], kind=f["kind"], channel=f["channel"],
                params=params, meta=meta,
                nuisance=f["nuisance"] if "nuisance" in f.files else None,
                noise_std=f["noise_std"] if "noise_std" in f.files else None,
            )


def atomic_savez(path: str | os.PathLike[str], arrays: dict[str, Any]) -> Path:
    """``np.savez`` written atomically: complete at ``path``, or not there at all."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    return Path(path)


def generate(
    stage_number: int,
    n: int,
    seed: int,
    *,
    fs: float = 100.0,
    duration: float = 2.0,
    exact_rate: bool = True,
    components: bool = False,
    progress: bool = False,
) -> SyntheticSet:
    """Generate ``n`` labelled windows of one benchmark stage.

    Parameters are drawn in physical units from named seed streams, then rendered on the grid
    ``t_n = n / fs``, ``n = 0 .. round(duration·fs) − 1``, in chunks of :data:`CHUNK` instances.
    ``components=True`` also returns the nuisance signal (everything but white noise and anomaly)
    and the per-sample noise std, which the oracle detector needs.
    """
    cfg = stage(stage_number)
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    if fs <= 0 or duration <= 0:
        raise ValueError(f"fs and duration must be positive, got fs={fs}, duration={duration}")
    n_steps = int(round(duration * fs))
    t = np.arange(n_steps) / fs
    rngs = streams(seed)

    params = draw_parameters(cfg, rngs, n)
    anomalies = sample_anomalies(rngs["anomalies"], cfg, n, duration, exact_rate)
    params.update(
        anomaly_start=anomalies.start, anomaly_duration=anomalies.duration,
        anomaly_offset=anomalies.offset,
    )

    shape = (n, n_steps, cfg.n_channels)
    X = np.empty(shape, dtype=np.float32)
    mask = np.empty(shape, dtype=bool)
    nuisance = np.empty(shape, dtype=np.float32) if components else None
    noise_std = np.empty(shape, dtype=np.float32) if components else None

    def render_chunk(index: int) -> None:
        sl = slice(index * CHUNK, min((index + 1) * CHUNK, n))
        clean, std = render_clean(cfg, t, {k: v[sl] for k, v in params.items()}, duration)
        # Each chunk's white noise has its own sub-stream, so chunks render in any order.
        z = np.random.default_rng(stream_seed(seed, "noise", index)).standard_normal(clean.shape)
        m = _slice_anomalies(anomalies, sl).mask(t, cfg.n_channels)
        X[sl] = clean + std * z + m * anomalies.offset[sl, None, None]
        mask[sl] = m
        if nuisance is not None and noise_std is not None:
            nuisance[sl] = clean
            noise_std[sl] = std

    n_chunks = -(-n // CHUNK)
    # numpy releases the GIL in its ufuncs, so threads render chunks in parallel.
    with ThreadPoolExecutor(max_workers=min(n_chunks, _n_workers())) as pool:
        jobs = pool.map(render_chunk, range(n_chunks))
        with Progress(n_chunks, f"stage {cfg.number}", "chunks", enabled=progress) as bar:
            for _ in jobs:
                bar.update(1)

    meta = {
        "stage": cfg.number, "stage_name": cfg.name, "seed": seed, "fs": fs, "n": n,
        "duration": duration, "n_steps": n_steps, "n_channels": cfg.n_channels,
        "channel_names": list(cfg.channel_names), "groups": list(cfg.groups),
        "spec_version": SPEC_VERSION, "exact_rate": exact_rate,
        "random_variables": list(cfg.variables),
        "n_random_variables": cfg.n_random_variables,
        "param_keys": [PARAM_PREFIX + k for k in params],
        "kinds": {"0": "normal", "1": "spike", "2": "local deviation"},
    }
    return SyntheticSet(
        X=X, y=anomalies.y, mask=mask, kind=anomalies.kind, channel=anomalies.channel,
        params=params, meta=meta, nuisance=nuisance, noise_std=noise_std,
    )


def draw_parameters(
    cfg: StageConfig, rngs: dict[str, np.random.Generator], n: int
) -> dict[str, NDArray[np.float64]]:
    """Every per-channel random variable of the stage, (n, C) each, each group from its stream."""
    parts = [("base", BASE_VARS, True), ("phase", PHASE_VARS, cfg.phase),
             ("speed", SPEED_VARS, cfg.speed_change),
             ("noise_change", NOISE_CHANGE_VARS, cfg.noise_change),
             ("bursts", BURST_VARS, cfg.bursts), ("impulses", IMPULSE_VARS, cfg.impulses)]
    params: dict[str, NDArray[np.float64]] = {}
    for stream, names, enabled in parts:
        if enabled:
            params.update(draw_uniform(rngs[stream], names, cfg.groups, n))
    return params


def render_clean(
    cfg: StageConfig, t: NDArray[np.float64], p: dict[str, NDArray[np.float64]], duration: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The noise-free, anomaly-free signal and the per-sample noise std, both (n, T, C)."""
    clean = comp.sinusoid(
        t, p["f"], p["amp"], p.get("phi"), p.get("t_change"), p.get("k_f"), p.get("k_a")
    )
    if cfg.bursts:
        clean += comp.hf_burst(t, p["t_hf"], p["dt_hf"], p["psi"], p["alpha_hf"], p["f_hf"])
    if cfg.impulses:
        clean += comp.impulses(t, p["omega"], p["imp_period"], p["beta"], duration)
    std = comp.noise_std(t, p["sigma"], p.get("d_sigma"), p.get("t_noisechange"))
    return clean, std


def _n_workers() -> int:
    return max(1, min(4, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                      else os.cpu_count() or 1))


def _slice_anomalies(a: Anomalies, sl: slice) -> Anomalies:
    return Anomalies(a.kind[sl], a.channel[sl], a.start[sl], a.duration[sl], a.offset[sl])
