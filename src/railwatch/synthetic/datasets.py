"""Generate labelled benchmark sets: windows ``X`` (n, T, C) float32 with their labels, every
sampled parameter and a ``meta`` record, as a :class:`railwatch.windows.WindowSet` (saved as one
window file).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

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
    STAGES,
    StageConfig,
    draw_uniform,
    stage,
)
from railwatch.windows import LOCAL, PARAM_PREFIX, SPIKE, WindowSet

#: Named seed streams, split from one SeedSequence. The index of a name never changes, so that
#: adding a component to a stage leaves every other component's draws untouched.
STREAMS = ("base", "phase", "speed", "noise_change", "noise", "bursts", "impulses", "anomalies")

#: Instances rendered at once: bounds memory at a few (chunk, T, C) float64 arrays.
CHUNK = 512

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
) -> WindowSet:
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
    return WindowSet(
        X=X, y=anomalies.y, mask=mask, kind=anomalies.kind, channel=anomalies.channel,
        params=params, meta=meta, nuisance=nuisance, noise_std=noise_std,
    )


def stage_examples(seed: int = 0) -> list[tuple[WindowSet, int]]:
    """For every stage, a small set and the index of one anomalous instance to show (Figure 1).

    Each stage draws from its own seed, ``seed`` + stage number: under one seed the anomalies of
    all stages coincide (the streams nest), which would show the same anomaly eight times. Odd
    stages show a spike, even stages a local deviation, so both kinds appear.
    """
    examples = []
    for number in sorted(STAGES):
        data = generate(number, 60, seed + number)
        want = SPIKE if number % 2 else LOCAL
        candidates = np.flatnonzero(data.kind == want)
        assert data.y is not None and data.kind is not None
        examples.append((data, int(candidates[0] if candidates.size
                                   else np.flatnonzero(data.y)[0])))
    return examples


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
