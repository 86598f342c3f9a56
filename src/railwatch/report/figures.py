"""Figures: the benchmark's and a detection's. Drawn on matplotlib ``Figure`` objects (no pyplot
state, no display needed)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from numpy.typing import NDArray

from railwatch.atomic import atomic_path
from railwatch.detectors import registry
from railwatch.trackmap.welds import GROUP as WELD_GROUP
from railwatch.windows import KIND_NAMES, WindowSet

if TYPE_CHECKING:
    from railwatch.detection.pipeline import Detection


def save_figure(fig: Figure, path: str | os.PathLike[str], dpi: int = 110) -> Path:
    """Render ``fig`` to ``path`` atomically (the format follows the file's suffix)."""
    FigureCanvasAgg(fig)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, bbox_inches="tight")
    return Path(path)


def stages_figure(examples: Sequence[tuple[WindowSet, int]], seed: int = 0) -> Figure:
    """The paper's missing Figure 1: one anomalous instance per stage, ``examples`` giving each
    stage's windows and the instance to draw (:func:`railwatch.synthetic.stage_examples`, drawn
    with ``seed``).

    Channels are stacked with a vertical offset. The anomaly is drawn in red on a red band;
    speed changes (t_change) are dashed, noise steps dotted, HF bursts shaded orange and impulse
    onsets marked with triangles, each on the channel it belongs to. Each title gives the number
    of underlying random variables.
    """
    fig = Figure(figsize=(15, 16), layout="constrained")
    axes = fig.subplots(4, 2).ravel()
    for ax, (data, i) in zip(axes, examples, strict=True):
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


def _draw_instance(ax, data: WindowSet, i: int) -> None:  # type: ignore[no-untyped-def]
    meta, p = data.meta, data.params
    _, mask, kind, channel = data.labels()
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
        m = mask[i, :, c]
        if m.any():
            ax.fill_between([t[m].min() - 0.5 / fs, t[m].max() + 0.5 / fs], lo, hi,
                            color="red", alpha=0.15, lw=0)
            ax.plot(t[m], x[m, c] + y0, "o-", color="red", ms=3, lw=1.5)
    if n_ch > 1:
        ax.set_yticks(offsets, meta["channel_names"])
    else:
        ax.set_ylabel("amplitude")
    what = KIND_NAMES[int(kind[i])]
    ch = meta["channel_names"][int(channel[i])]
    ax.set_title(
        f"Stage {meta['stage']}: {meta['stage_name']}  ·  # random variables: "
        f"{meta['n_random_variables']}\n{what} on {ch}, offset {p['anomaly_offset'][i]:+.2f}",
        fontsize=10,
    )
    ax.set_xlim(0, meta["duration"])
    ax.set_xlabel("time (s)")
    ax.grid(alpha=0.3)


# ----------------------------------------------------------------------------- benchmark figures
def auc_vs_stage_figure(
    records: list[dict[str, Any]], detectors: list[str], metric: str = "auc_instance"
) -> Figure:
    """AUC against stage for every detector (mean ± std over seeds), the oracle ceiling dashed
    black, and the paper's Table I as faint dotted lines in the same colours."""
    from railwatch.report.tables import PAPER_TABLE1, aggregate, mean_std

    agg = aggregate(records, metric)
    stages = sorted({int(r["stage"]) for r in records})
    fig = Figure(figsize=(12, 5.5), layout="constrained")
    ax = fig.subplots()
    # a NAME+glr row (the same model, scored by the shared GLR scan) takes NAME's colour, dashed
    base = {d: registry.variant_of(d) if registry.variant_of(d) in detectors else d
            for d in detectors}
    own = [d for d in detectors if base[d] == d]
    colours = dict(zip(own, _palette(len(own)), strict=True))
    for d in detectors:
        stats = [mean_std(agg.get((s, d), [])) for s in stages]
        mean = np.array([m for m, _ in stats])
        std = np.array([sd for _, sd in stats])
        if registry.role(d) == "ceiling":
            ax.plot(stages, mean, "k--", lw=2.2, label=f"{d} (ceiling)")
            continue
        variant = base[d] != d
        ax.errorbar(stages, mean, yerr=std, marker="s" if variant else "o", ms=4, lw=1.6,
                    capsize=3, color=colours[base[d]], ls="--" if variant else "-", label=d)
        if metric == "auc_instance" and d in PAPER_TABLE1:
            ax.plot(stages, [PAPER_TABLE1[d][s - 1] for s in stages], ":", lw=1.2,
                    color=colours[d], alpha=0.7)
    ax.set_xticks(stages)
    ax.set_xlabel("stage (1 baseline · 2 speed · 3 two channels · 4 noise · 5 six channels · "
                  "6 odds · 7 HF bursts · 8 impulses)", fontsize=9)
    ax.set_ylabel(metric)
    ax.grid(alpha=0.3)
    notes = (["dotted: the paper's Table I"] if metric == "auc_instance"
             and any(d in PAPER_TABLE1 for d in detectors) else []) \
        + (["dashed: a model's residual scored by the shared GLR scan"]
           if any(base[d] != d for d in detectors) else [])
    ax.set_title(f"{metric} per stage" + (f" ({'; '.join(notes)})" if notes else ""))
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.01, 0.5))  # beside the lines
    return fig


def score_histograms_figure(
    arrays: dict[tuple[int, str], dict[str, Any]], stages: list[int], detectors: list[str]
) -> Figure:
    """Instance-score histograms, normal vs anomalous, one panel per stage × detector."""
    fig = Figure(figsize=(2.2 * len(stages) + 1, 1.6 * len(detectors) + 1), layout="constrained")
    axes = np.atleast_2d(fig.subplots(len(detectors), len(stages), squeeze=False))
    for i, d in enumerate(detectors):
        for j, s in enumerate(stages):
            ax = axes[i, j]
            a = arrays.get((s, d))
            if a is None:
                ax.set_axis_off()
                continue
            score, y = a["instance"].astype(np.float64), a["y"].astype(bool)
            lo, hi = np.percentile(score, [0.5, 99.5])
            bins = np.linspace(lo, hi if hi > lo else lo + 1, 40)
            ax.hist(np.clip(score[~y], lo, hi), bins=bins, density=True, alpha=0.6,
                    color="tab:blue", label="normal")
            ax.hist(np.clip(score[y], lo, hi), bins=bins, density=True, alpha=0.6,
                    color="tab:red", label="anomalous")
            ax.set_yticks([])
            ax.tick_params(labelsize=6)
            if i == 0:
                ax.set_title(f"stage {s}", fontsize=9)
            if j == 0:
                ax.set_ylabel(d, fontsize=8)
    axes[0, 0].legend(fontsize=6)
    fig.suptitle("Instance scores of the test windows: normal (blue) vs anomalous (red)")
    return fig


def attention_example_figure(
    x: NDArray[Any], mask: NDArray[Any], point: NDArray[Any], attention: NDArray[Any],
    title: str, fs: float = 100.0,
) -> Figure:
    """One anomalous window: the signal with the anomaly marked, the attention map of the
    anomalous channel (averaged over layers and heads) and the attention-derived score trace.

    ``x``, ``mask`` (T, C); ``point`` (T,); ``attention`` (L_q, L_k), any token grid.
    """
    t = np.arange(x.shape[0]) / fs
    fig = Figure(figsize=(10, 8), layout="constrained")
    gs = fig.add_gridspec(3, 1, height_ratios=[1, 2.2, 1])
    ax0 = fig.add_subplot(gs[0])
    ch = int(mask.any(axis=0).argmax()) if mask.any() else 0
    for c in range(x.shape[1]):
        ax0.plot(t, x[:, c] - 4 * c, lw=0.8, color="tab:red" if c == ch else "tab:blue",
                 alpha=1 if c == ch else 0.5)
    span = mask[:, ch]
    if span.any():
        ax0.axvspan(t[span].min() - 0.5 / fs, t[span].max() + 0.5 / fs, color="red", alpha=0.15)
    ax0.set_title(title, fontsize=10)
    ax0.set_yticks([])
    ax0.set_xlim(0, t[-1])
    ax1 = fig.add_subplot(gs[1])
    n_tok = attention.shape[-1]
    im = ax1.imshow(attention, aspect="auto", cmap="viridis", origin="upper",
                    extent=(0, t[-1] + 1 / fs, t[-1] + 1 / fs, 0))
    if span.any():
        for edge in (t[span].min(), t[span].max() + 1 / fs):
            ax1.axvline(edge, color="red", lw=1)
    ax1.set_xlabel("key time (s)")
    ax1.set_ylabel("query time (s)")
    ax1.set_title(f"self-attention of the anomalous channel ({n_tok} tokens; mean over layers "
                  "and heads)", fontsize=10)
    fig.colorbar(im, ax=ax1, shrink=0.8)
    ax2 = fig.add_subplot(gs[2], sharex=ax0)
    ax2.plot(t, point, color="black", lw=1)
    if span.any():
        ax2.axvspan(t[span].min() - 0.5 / fs, t[span].max() + 0.5 / fs, color="red", alpha=0.15)
    ax2.set_xlabel("time (s)")
    ax2.set_ylabel("point score")
    return fig


def _palette(n: int) -> list[Any]:
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return [cmap(i % 10) for i in range(n)]


def plot_detection(det: Detection, path: str | os.PathLike[str], title: str = "",
                   truth: Sequence[float] | None = None) -> Path:
    """The score trace along time with the threshold, events shaded, optional true defects."""
    fig = Figure(figsize=(12, 3.6), layout="constrained")
    ax = fig.subplots()
    ax.plot(det.trace.time, det.trace.score, lw=0.6, color="0.3", label="score (max per 0.1 s)")
    ax.axhline(det.threshold, color="tab:red", ls="--", lw=1, label="threshold")
    for i, e in enumerate(det.events):
        ax.axvspan(e.start_s, e.end_s, color="tab:red", alpha=0.35, lw=0,
                   label="event" if i == 0 else None)
        ax.annotate(e.channel, (e.peak_s, e.score), fontsize=6, rotation=90, va="bottom",
                    ha="center", color="tab:red")
    for i, at in enumerate(truth or []):
        ax.axvline(at, color="tab:green", lw=0.8, alpha=0.7, ymax=0.08,
                   label="true defect" if i == 0 else None)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("anomaly score")
    finite = np.asarray(det.trace.score, dtype=float)
    finite = finite[np.isfinite(finite)]
    if len(finite) and det.threshold > 0 and finite.max() > 30 * det.threshold:
        ax.set_yscale("symlog", linthresh=1.0)  # scores over orders of magnitude
        ax.set_ylim(bottom=0.0)
    ax.set_title(title or f"{len(det.events)} events in {det.duration_s / 60:.1f} min")
    t = np.asarray(det.trace.time, dtype=float)
    p = np.asarray(det.trace.position, dtype=float)
    if len(t) > 1 and np.isfinite(p).all() and (np.diff(p) > 0).all():
        def to_position(x: Any) -> Any:
            return np.interp(x, t, p)

        def to_time(x: Any) -> Any:
            return np.interp(x, p, t)

        secax = ax.secondary_xaxis("top", functions=(to_position, to_time))
        secax.set_xlabel("track position (m)")
    ax.legend(loc="upper right", fontsize=7, ncols=4)
    save_figure(fig, Path(path))
    return Path(path)


def _draw_places(ax: Any, places: Sequence[Any], value: str, register: bool,
                 weld_layer: bool) -> None:
    """The reported places of one layer of a fused map at their ``value`` (red: unexplained,
    grey: on an asset): the event layer's, or the weld layer's own (group ``rail height``)."""
    mine = [loc for loc in places if (getattr(loc, "group", "") == WELD_GROUP) == weld_layer]
    on = [loc for loc in mine if getattr(loc, "asset", "") not in ("", "unexplained")]
    rest = [loc for loc in mine if loc not in on]
    ax.plot([loc.position_m / 1000 for loc in rest], [getattr(loc, value) for loc in rest], "o",
            mfc="none", color="tab:red", ms=6,
            label="reported place, unexplained" if register else "reported place")
    if on:
        ax.plot([loc.position_m / 1000 for loc in on], [getattr(loc, value) for loc in on], "o",
                mfc="none", color="0.45", ms=6, label="reported place on an asset")


def track_map_figure(locations: Sequence[Any], passes: Sequence[Any], reported: Sequence[Any],
                     truth_m: NDArray[Any] | None = None, fused: Any = None,
                     level: float | None = None, assets: Sequence[Any] = ()) -> Figure:
    """The track with its places: with ``fused`` (a fused map) the evidence along the track
    and the reporting ``level``, reported places as red dots (and, with a weld layer, the weld
    test along the track below, with its own places); otherwise each place's share of
    the passes that covered it as a bar, reported ones red. With a register (``assets`` on the
    line, and places labelled by them), a reported place on an asset is grey and the assets
    are grey ticks. True defects, where known, as green ticks; the stretch each pass covered
    below."""
    welds = getattr(fused, "welds", None) if fused is not None else None
    fig = Figure(figsize=(13, 5.8 if welds is not None else 4.2), layout="constrained")
    axes = fig.subplots(3 if welds is not None else 2, 1, sharex=True,
                        height_ratios=[3, 2, 1] if welds is not None else [3, 1])
    ax, cov = axes[0], axes[-1]
    shown = {id(loc) for loc in reported}
    if fused is not None:
        ax.plot(fused.grid / 1000, fused.evidence, lw=0.5, color="0.35",
                label="evidence fused over the passes")
        if level is not None:
            ax.axhline(level, color="tab:red", lw=0.8, ls="--", label="reporting level")
        rep = [loc for loc in locations if id(loc) in shown]
        _draw_places(ax, rep, "evidence", bool(len(assets)), weld_layer=False)
        ax.set_ylabel("evidence (−log10 p)")
        if welds is not None:
            wax = axes[1]
            wax.plot(welds.grid / 1000, welds.top, lw=0.5, color="0.35",
                     label="weld test fused over the passes")
            wax.axhline(welds.level(0.1), color="tab:red", lw=0.8, ls="--",
                        label="its level: 0.1 places per km")
            _draw_places(wax, rep, "weld_z", bool(len(assets)), weld_layer=True)
            wax.set_ylabel("weld test (z)")
            # Joints, steps and assets reach hundreds: the scale of the welds and the level.
            own = [loc.weld_z for loc in rep if getattr(loc, "group", "") == WELD_GROUP]
            wax.set_ylim(0.0, max([4 * welds.level(0.1), *(1.3 * z for z in own)]))
            wax.grid(alpha=0.3)
            wax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
        bottom = -0.04 * max(float(np.nanmax(fused.evidence, initial=1.0)), 1.0)
    else:
        for loc in locations:
            colour = "tab:red" if id(loc) in shown else "0.65"
            ax.vlines(loc.position_m / 1000, 0, loc.share, color=colour, lw=1.6)
        ax.set_ylim(-0.08, 1.05)
        ax.set_ylabel("passes seen / covered")
        bottom = -0.04
    if truth_m is not None and len(truth_m):
        starts = np.asarray(truth_m, dtype=float).reshape(len(truth_m), -1)[:, 0]
        ax.plot(starts / 1000, np.full(len(starts), bottom), "^",
                color="tab:green", ms=5, label="true defect")
    if len(assets):
        ax.plot([0.5 * (a.start_m + a.end_m) / 1000 for a in assets],
                np.full(len(assets), 2 * bottom), "v", color="0.45", ms=5,
                label="asset (register)")
    if fused is not None or (truth_m is not None and len(truth_m)) or len(assets):
        ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)  # beside the track
    unexplained = sum(getattr(loc, "asset", "") == "unexplained" for loc in reported)
    ax.set_title(f"{len(reported)} reported places "
                 + (f"({unexplained} unexplained, red; on assets grey)" if len(assets)
                    else "(red)") + f" of {len(locations)} listed, {len(passes)} passes")
    ax.grid(alpha=0.3)
    for i, p in enumerate(passes):
        cov.plot(np.array(p.covered) / 1000, [i, i], lw=3, color="tab:blue")
    cov.set_yticks(range(len(passes)), [p.name for p in passes], fontsize=6)
    cov.set_xlabel("track position (km)")
    return fig
