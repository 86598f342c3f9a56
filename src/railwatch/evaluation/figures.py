"""Figures. Drawn on matplotlib ``Figure`` objects (no pyplot state, no display needed)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from railwatch.atomic import atomic_path
from railwatch.synthetic import STAGES, SyntheticSet, generate
from railwatch.synthetic.anomalies import LOCAL, SPIKE

KIND_NAMES = {SPIKE: "spike", LOCAL: "local deviation"}


def save_figure(fig: Figure, path: str | os.PathLike[str], dpi: int = 110) -> Path:
    """Render ``fig`` to ``path`` atomically (the format follows the file's suffix)."""
    FigureCanvasAgg(fig)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, bbox_inches="tight")
    return Path(path)


def _example(stage_number: int, seed: int) -> tuple[SyntheticSet, int]:
    """A small set of the stage and the index of one anomalous instance to show.

    Each stage draws from its own seed: under one seed the anomalies of all stages coincide
    (the streams nest), which would show the same anomaly eight times.

    Odd stages show a spike, even stages a local deviation, so both kinds appear.
    """
    data = generate(stage_number, 60, seed)
    want = SPIKE if stage_number % 2 else LOCAL
    candidates = np.flatnonzero(data.kind == want)
    return data, int(candidates[0] if candidates.size else np.flatnonzero(data.y)[0])


def stages_figure(seed: int = 0) -> Figure:
    """The paper's missing Figure 1: one anomalous instance per stage.

    Channels are stacked with a vertical offset. The anomaly is drawn in red on a red band;
    speed changes (t_change) are dashed, noise steps dotted, HF bursts shaded orange and impulse
    onsets marked with triangles, each on the channel it belongs to. Each title gives the number
    of underlying random variables.
    """
    fig = Figure(figsize=(15, 16), layout="constrained")
    axes = fig.subplots(4, 2).ravel()
    for ax, number in zip(axes, sorted(STAGES), strict=True):
        data, i = _example(number, seed + number)
        _draw_instance(ax, data, i)
    handles = [
        ("red", "-", "anomaly (injected offset)"), ("tab:green", "--", "t_change (speed change)"),
        ("tab:purple", ":", "noise step"), ("orange", "-", "HF burst (shaded)"),
        ("black", "none", "impulse onset (▲)"),
    ]
    fig.legend(
        [Line2D([], [], color=c, ls=ls, marker="^" if ls == "none" else None, lw=2)
         for c, ls, _ in handles],
        [label for *_, label in handles], loc="outside lower center", ncols=5, fontsize=10,
    )
    fig.suptitle("The incremental synthetic benchmark: one anomalous window per stage "
                 f"(seed {seed} + stage number, 100 Hz, 2 s)", fontsize=13)
    return fig


def _draw_instance(ax, data: SyntheticSet, i: int) -> None:  # type: ignore[no-untyped-def]
    meta, p = data.meta, data.params
    fs, n_ch = meta["fs"], meta["n_channels"]
    t = np.arange(meta["n_steps"]) / fs
    x = data.X[i].astype(np.float64)  # (T, C)
    spacing = 1.2 * float(np.max(np.abs(x))) * 2 if n_ch > 1 else 0.0
    offsets = -spacing * np.arange(n_ch)
    half = spacing / 2 if n_ch > 1 else 1.2 * float(np.max(np.abs(x)))
    for c in range(n_ch):
        y0 = offsets[c]
        lo, hi = y0 - half, y0 + half
        ax.plot(t, x[:, c] + y0, lw=0.9, color="tab:blue")
        if "t_change" in p:
            ax.vlines(p["t_change"][i, c], lo, hi, colors="tab:green", linestyles="--", lw=1.2)
        if "t_noisechange" in p:
            ax.vlines(p["t_noisechange"][i, c], lo, hi, colors="tab:purple", linestyles=":",
                      lw=1.4)
        if "t_hf" in p:
            t0 = p["t_hf"][i, c]
            ax.fill_between([t0, t0 + p["dt_hf"][i, c]], lo, hi, color="orange", alpha=0.25, lw=0)
        if "imp_period" in p:
            onsets = np.arange(int(np.floor(meta["duration"] / p["imp_period"][i, c]))) \
                * p["imp_period"][i, c]
            ax.plot(onsets, np.full(onsets.shape, lo + 0.05 * (hi - lo)), "^", color="black",
                    ms=4)
        m = data.mask[i, :, c]
        if m.any():
            ax.fill_between([t[m].min() - 0.5 / fs, t[m].max() + 0.5 / fs], lo, hi,
                            color="red", alpha=0.15, lw=0)
            ax.plot(t[m], x[m, c] + y0, "o-", color="red", ms=3, lw=1.5)
    if n_ch > 1:
        ax.set_yticks(offsets, meta["channel_names"])
    else:
        ax.set_ylabel("amplitude")
    kind = KIND_NAMES[int(data.kind[i])]
    ch = meta["channel_names"][int(data.channel[i])]
    ax.set_title(
        f"Stage {meta['stage']}: {meta['stage_name']}  ·  # random variables: "
        f"{meta['n_random_variables']}\n{kind} on {ch}, offset {p['anomaly_offset'][i]:+.2f}",
        fontsize=10,
    )
    ax.set_xlim(0, meta["duration"])
    ax.set_xlabel("time (s)")
    ax.grid(alpha=0.3)
