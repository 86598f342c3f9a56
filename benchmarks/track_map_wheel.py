"""Wheel-periodic impulses out of the signal before the detector (`train --wheel-comb`, its
turn estimated or, as an oracle, the synthesiser's), on development tracks.

Stage 8 adds to every channel of every pass one impulse per turn of a wheel, at a spacing L
along the track (2.25-11.25 m, drawn per pass and channel); they are what the fused map loses
on stage 8 (docs/track-map.md). Here each pass's raw signal (2000 Hz) has them taken out by a
**comb in distance**: every sample less the mean of the samples one and two wheel turns before
and after it (±L, ±2L along the pass's recorded position, linear interpolation; at the ends of
the pass the turns that exist; `railwatch.recordings.wheel`), then the matched filter is trained
on passes 1-2 and passes 3-12 are scanned and mapped as in `benchmarks/track_map.py` (odometry
alone, `track-map`'s default rule). The wheel turn L of each pass and channel is:

1. **none**: no comb (the scans of `benchmarks/track_map.py`);
2. **true L** (an oracle: the synthesiser's own spacing);
3. **estimated L**: from the pass's own signal, the peak of its cepstrum over distance (the
   signal on a 2-cm grid of its recorded position, the log power spectrum of each 200-m block,
   Hann window, inverse-transformed and averaged over the blocks) between 1.5 and 15 m; the
   comb only where that peak stands out of the cepstrum over the range by at least 5 robust
   standard deviations (median and MAD), otherwise the channel is left as it is. A peak at a
   multiple of L combs the impulses away too. This is what `train --wheel-comb` does.

Also measured: how often the estimate passes the gate and lands on L or a multiple (within
3 %), on the stage-8 tracks, and how often the gate passes on the stage-5 development track
(no impulses: each pass should be left as it is).

Stage-8 tracks of seeds 12-19 (the development tracks of `benchmarks/track_map.py`,
`track_map_fusion.py` and `track_map_frame.py`; made here if missing), the stage-5 one of seed
12. Run after `benchmarks/track_map.py`: `python -m benchmarks track_map_wheel`, about 15
minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from benchmarks import track_map as bench

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ('track_map',)
PAGE = "docs/results/track-map/track-map-wheel.md"
MINUTES = 15

ROLES = bench.DEV_ROLES
SUBSETS = {"3-7": slice(0, 5), "8-12": slice(5, 10), "3-12": slice(0, 10)}
TURNS = 2


def true_periods(pass_seed: int) -> list[float]:
    """The synthesiser's impulse spacing of each channel of the pass with this seed
    (:func:`railwatch.synthetic.runs._impulses`: ω, T, β then the first impulse, per channel,
    from the pass's impulse stream)."""
    from railwatch.synthetic.runs import CHANNEL_GROUPS, MEAN_SPEED
    from railwatch.synthetic.stages import GROUPS

    rng = np.random.default_rng([pass_seed, 208])
    out = []
    for group in CHANNEL_GROUPS:
        g = GROUPS[group]
        rng.uniform(*g.omega)
        period = rng.uniform(*g.imp_period)
        rng.uniform(*g.beta)
        rng.uniform(0.0, period * MEAN_SPEED)
        out.append(period * MEAN_SPEED)
    return out


def combed_track(work: Path, kind: str, role: str, variant: str,
                 stats: list[tuple[float, float, float]]) -> Path:
    """The track's folder with every pass combed (``variant``: "true L" or "estimated L");
    ``stats`` gets (estimated L, z, true L) per pass and channel."""
    from railwatch.recordings import wheel
    from railwatch.recordings.readers import Chunk
    from railwatch.synthetic.runs import CHANNELS

    src = bench.track(work, kind, role)
    dst = work / f"{src.name}-wheel-{'true' if variant == 'true L' else 'estimated'}"
    dst.mkdir(exist_ok=True)
    for f in ["layout.toml", "track.defects.csv", *(p.name for p in src.glob("pass*.csv"))]:
        shutil.copy(src / f, dst / f)
    for i in range(1, bench.PASSES + 1):
        data = pd.read_parquet(src / f"pass{i:02d}.parquet")
        fs = 1.0 / float(np.median(np.diff(data["time"].to_numpy()[:1000])))
        chunk = Chunk(0, data[list(CHANNELS)].to_numpy(np.float32),
                      position=data["position"].to_numpy())
        peaks = wheel.cepstral_peaks([chunk], fs, len(CHANNELS))
        truth = true_periods(ROLES[role] * 1000 + i) if kind == "stage 8" else [np.nan] * 6
        stats += [(turn, z, true) for (turn, z), true in zip(peaks, truth, strict=True)]
        out = dst / f"pass{i:02d}.parquet"
        if out.exists():
            continue
        turns = [t if np.isfinite(t) else None for t in truth] if variant == "true L" else \
            [turn if z >= wheel.GATE else None for turn, z in peaks]
        comb = wheel.Comb(turns, TURNS, fs)
        combed = np.concatenate([c.data for c in comb.push(chunk) + comb.close()])
        data[list(CHANNELS)] = combed
        data.to_parquet(out)
    return dst


def curve(scan: Path, truth: Path) -> list[tuple[float, float]]:
    from railwatch import trackmap as tm
    from railwatch.evaluation import maps as em

    passes = tm.read_scan(scan)
    defects = em.read_truth(truth)
    cells = []
    for subset in SUBSETS.values():
        use = passes[subset]
        lo, hi = tm.covered_range(use)
        s = em.score_locations(tm.reported_fused(tm.fused_map(use)[0]),
                               em.on_stretch(defects, lo, hi), hi - lo)
        cells.append((s["recall"], s["false_per_km"]))
    return cells


def text(cells: list[tuple[float, float]]) -> str:
    return " | ".join(f"{r:.0%} / {f:.2f}" for r, f in cells)


def summary(per_track: list[list[tuple[float, float]]]) -> str:
    """Mean recall / false per km of the 5-pass maps (lowest recall) | of the 10-pass maps."""
    five = np.array([c for cells in per_track for c in cells[:2]])
    ten = np.array([cells[2] for cells in per_track])
    return (f"{five[:, 0].mean():.1%} / {five[:, 1].mean():.2f} ({five[:, 0].min():.0%}) | "
            f"{ten[:, 0].mean():.1%} / {ten[:, 1].mean():.2f}")


def main() -> None:
    np.seterr(all="ignore")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("runs/bench-track-map"))
    parser.add_argument("--out", type=Path, default=Path(PAGE))
    args = parser.parse_args()
    from railwatch.recordings import wheel
    from railwatch.report.pages import write_markdown

    bench.SEEDS.update(ROLES)
    low = min(bench.FACTORS)
    rows = ["| nuisance | track (seed) | wheel turn L | " + " | ".join(
        f"passes {s}" for s in SUBSETS) + " |", "|---|---|---|" + "---|" * len(SUBSETS)]
    gate_rows = []
    runs = [*(("stage 8", role) for role in ROLES), ("stage 5", "dev")]
    found: dict[str, list[list[tuple[float, float]]]] = {}
    for kind, role in runs:
        folder = bench.track(args.work, kind, role)
        plain = bench.above(bench.scanned(folder, "matched-filter", low), 1.0, low)
        cells = curve(plain, folder / "track.defects.csv")
        rows.append(f"| {kind} | {ROLES[role]} | none | {text(cells)} |")
        if kind == "stage 8":
            found.setdefault("none", []).append(cells)
        for variant in ("true L", "estimated L") if kind == "stage 8" else ("estimated L",):
            stats: list[tuple[float, float, float]] = []
            combed = combed_track(args.work, kind, role, variant, stats)
            scan = bench.above(bench.scanned(combed, "matched-filter", low), 1.0, low)
            cells = curve(scan, folder / "track.defects.csv")
            rows.append(f"| {kind} | {ROLES[role]} | {variant} | {text(cells)} |")
            print(rows[-1], flush=True)
            if kind == "stage 8":
                found.setdefault(variant, []).append(cells)
            if variant == "estimated L":
                s = np.array(stats)
                passed = s[:, 1] >= wheel.GATE
                ratio = s[:, 0] / s[:, 2]
                on_l = np.isfinite(ratio) & (np.abs(ratio - np.round(ratio))
                                             < 0.03 * np.maximum(np.round(ratio), 1)) \
                    & (np.round(ratio) >= 1)
                gate_rows.append(
                    f"| {kind} | {ROLES[role]} | {len(s)} | {int(passed.sum())} | "
                    + (f"{int((passed & on_l).sum())} | {int((~passed & on_l).sum())} |"
                       if kind == "stage 8" else "– (no impulses) | – |"))
    command, items = bench.page_head(__name__, __doc__)
    lines = ["# Wheel-periodic impulses combed out before the detector (`train --wheel-comb`)", "",
             command, "", *items, "",
             "Recall within ±2 m / false places per km of the fused map (matched filter, "
             "odometry alone):", "", *rows, "",
             f"Over the {len(ROLES)} stage-8 tracks: mean recall / false places per km of the "
             f"{2 * len(ROLES)} maps from 5 passes (the lowest recall in brackets), and of the "
             f"{len(ROLES)} maps from 10:", "",
             "| wheel turn L | from 5 passes | from 10 passes |", "|---|---|---|",
             *(f"| {variant} | {summary(cells)} |" for variant, cells in found.items()), "",
             "The estimate of L, per pass and channel (12 passes × 6 channels per track):", "",
             "| nuisance | track (seed) | channels | gate passed | of those on L or a multiple "
             "| on L or a multiple but below the gate |", "|---|---|---|---|---|---|",
             *gate_rows]
    print(write_markdown(args.out, lines))


if __name__ == "__main__":
    main()
