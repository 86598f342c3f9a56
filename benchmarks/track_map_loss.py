"""Where the track map loses defects: the per-pass detector, the alignment, or the map's frame.

On the development tracks of `benchmarks/track_map.py` (seed 12; stage-5-like and stage-8-like
nuisance with loud stretches; passes 3-12, each detector trained on passes 1-2), for every
crossing of a defect by a pass:

1. **What the data allow** (an oracle that knows the synthesiser's clean signal and noise):
   the defect's signal-to-noise ratio at the model's 100 Hz, the best box sum of the true
   residual near the crossing over the true noise std;
2. **What each detector keeps**: whether the detector's per-sample score (the scan's profile) at
   the crossing is in the top 1 % of the same pass and channel's scores within ±100 m outside
   ±10 m (the fused map's first calibration, on the raw samples: a yardstick of the
   detector, kept as it was);
3. **What the map makes of it**: recall and false places per km of the fused map from 5 and 10
   passes with positions as recorded by odometry alone (the default) and by a GNSS-aided
   odometry, and at their true positions (an odometry without errors), each aligned by
   `track-map` as usual.

The matched filter is measured twice: with its default ridge (0.1) and with the ridge it had
before (1e-6), to show what the ridge is for. Run after `benchmarks/track_map.py` (which
makes the tracks and scans); about 10 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import numpy as np

from benchmarks import track_map as bench

#: What this benchmark reads that others made (run them first, same --work), the page
#: it writes (None: it prints its table) and about how long it takes on 2 cores.
NEEDS: tuple[str, ...] = ('track_map',)
PAGE = "docs/results/track-map/track-map-loss.md"
MINUTES = 10

DETECTORS = {"stage 5": ("context-glr", "aft-attention", "matched-filter",
                         "matched-filter ridge 1e-6"),
             "stage 8": ("context-glr", "matched-filter", "matched-filter ridge 1e-6")}
#: An odometry without errors: the passes' true positions.
TRUE_POSITIONS = (0.0, 0.0, 0.0)
FS = 2000.0
RATE = 100  # the model's rate


def scan_of(folder: Path, detector: str) -> Path:
    """The detector's scan of the development track at the track-map benchmark's lowest
    threshold (made there; the old-ridge matched filter trained and scanned here)."""
    if detector == "matched-filter ridge 1e-6":
        return bench.scanned(folder, "matched-filter", min(bench.FACTORS), ("ridge=1e-6",),
                             "matched-filter-ridge1e-6")
    return bench.scanned(folder, detector, min(bench.FACTORS))


def passes_with_truth(kind: str):  # type: ignore[no-untyped-def]
    """Per mapped pass: the pass (its true positions, crossings) and its clean signal."""
    import railwatch.synthetic.track as T

    stage = int(bench.KINDS[kind][1])
    track = T.make_track(10_000.0, 40, seed=bench.SEEDS["dev"], stage=stage, loud_stretches=True)
    clean: dict[str, np.ndarray] = {}
    render = T.render

    def render_both(rng, burst_rng, impulse_rng, t, position, scale, gain, stage_,  # type: ignore[no-untyped-def]  # noqa: E501
                    fs):
        copies = [copy.deepcopy(r) for r in (rng, burst_rng, impulse_rng)]
        clean["signal"] = render(*copies, t, position, scale, 0.0, stage_, fs)
        return render(rng, burst_rng, impulse_rng, t, position, scale, gain, stage_, fs)

    T.render = render_both  # the same draws, once without noise: the oracle's clean signal
    try:
        for i in range(2, bench.PASSES):
            p = T.synthesize_pass(track, seed=bench.SEEDS["dev"] * 1000 + i + 1, fs=FS,
                                  direction=1 if i % 2 == 0 else -1)
            yield f"pass{i + 1:02d}", p, clean["signal"].astype(float)
    finally:
        T.render = render


def oracle_snr(p, clean: np.ndarray) -> list[float]:  # type: ignore[no-untyped-def]
    """Per crossing: the best box sum of the true residual at 100 Hz near it over the noise's
    std there."""
    from scipy.ndimage import uniform_filter1d
    from scipy.signal import resample_poly

    from railwatch.synthetic.runs import CHANNELS

    residual = p.run.data.astype(float) - clean
    noise = residual.copy()
    for row in p.crossings:
        i0 = int(round(row["time_s"] * FS))
        noise[i0:i0 + int(round(row["duration_s"] * FS)), CHANNELS.index(row["channel"])] \
            -= row["offset"]
    down = int(FS // RATE)
    r, n = resample_poly(residual, 1, down, axis=0), resample_poly(noise, 1, down, axis=0)
    sigma = np.sqrt(uniform_filter1d(n ** 2, 21, axis=0))
    out = []
    for row in p.crossings:
        c = CHANNELS.index(row["channel"])
        k0 = int(row["time_s"] * RATE)
        k1 = int(np.ceil((row["time_s"] + row["duration_s"]) * RATE)) + 1
        seg = r[max(0, k0 - 2):k1 + 2, c]
        cs = np.concatenate([[0.0], np.cumsum(seg)])
        best = max(abs(cs[b] - cs[a]) / np.sqrt(b - a) for a in range(len(seg))
                   for b in range(a + 1, len(seg) + 1))
        out.append(best / sigma[k0, c])
    return out


def top_share(scan: Path, name: str, p) -> list[bool]:  # type: ignore[no-untyped-def]
    """Per crossing: the detector's score there in the top 1 % of its neighbourhood."""
    with np.load(scan / f"{name}.profile.npz") as f:
        t, x, score = f["time_s"], f["position_m"], f["channel_score"].astype(float)
        channels = [str(c) for c in f["channels"]]
    out = []
    for row in p.crossings:
        c = channels.index(row["channel"])
        here_m = np.abs(t - row["center_s"]) <= 0.06 + row["duration_s"] / 2
        here = score[here_m, c].max()
        d = np.abs(x - row["recorded_m"])
        around = score[(d <= 100) & (d > 10), c]
        out.append((np.sum(around >= here) + 1) / (len(around) + 1) <= 0.01)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("runs/bench-track-map"))
    parser.add_argument("--out", type=Path, default=Path(PAGE))
    args = parser.parse_args()
    from railwatch.report.pages import write_markdown

    per_pass = ["| nuisance | crossings | oracle SNR ≥ 5 | oracle SNR, median | "
                + " | ".join(f"top 1 %: {d}" for d in DETECTORS["stage 5"]) + " |",
                "|---|---|---|---|" + "---|" * len(DETECTORS["stage 5"])]
    maps = ["| nuisance | detector | passes | odometry alone | "
            "GNSS-aided positions | true positions |", "|---|---|---|---|---|---|"]
    for kind, detectors in DETECTORS.items():
        folder = bench.track(args.work, kind, "dev")
        scans = {d: scan_of(folder, d) for d in detectors}
        snr: list[float] = []
        tops: dict[str, list[bool]] = {d: [] for d in detectors}
        for name, p, clean in passes_with_truth(kind):
            snr += oracle_snr(p, clean)
            for d in detectors:
                tops[d] += top_share(scans[d], name, p)
        cells = [f"{np.mean(tops[d]):.0%}" if d in tops else "" for d in DETECTORS["stage 5"]]
        per_pass.append(f"| {kind} | {len(snr)} | {np.mean(np.array(snr) >= 5):.0%} | "
                        f"{np.median(snr):.0f} | " + " | ".join(cells) + " |")
        print(per_pass[-1], flush=True)
        for d in detectors:
            events = bench.above(scans[d], 1.0, min(bench.FACTORS))
            curves = [bench.curve(placed, folder / "track.defects.csv", None) for placed in (
                events,
                bench.with_odometry(events, folder, kind, "dev", bench.ODOMETRIES["GNSS-aided"]),
                bench.with_odometry(events, folder, kind, "dev", TRUE_POSITIONS, "-true"))]
            for k in (5, 10):
                cells = [next(r for r in rows if r["passes"] == k) for rows in curves]
                maps.append(f"| {kind} | {d} | {k} | " + " | ".join(
                    f"{c['recall']:.0%} / {c['false_per_km']:.1f}" for c in cells) + " |")
                print(maps[-1], flush=True)
    command, items = bench.page_head(__name__, __doc__)
    lines = [
        "# Where the track map loses defects",
        "",
        command,
        "",
        *items,
        "",
        "Per crossing of a defect by a pass (passes 3-12 of the development tracks):",
        "",
        *per_pass,
        "",
        "The fused map (recall / false places per km, `track-map`'s default rule), by how the "
        "passes are placed on the track:",
        "",
        *maps,
    ]
    print(write_markdown(args.out, lines))


if __name__ == "__main__":
    main()
