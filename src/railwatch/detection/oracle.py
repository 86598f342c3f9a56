"""The recordings oracle: the events that a synthetic run allows at the pipeline's rate.

A run made with ``synthesize_run(components=True)`` carries its nuisance signal (sinusoids,
bursts, impulses) and its white noise's std at every sample. The oracle knows both, as the
window oracle does (:mod:`railwatch.detectors.oracle`):

1. it whitens the run at its own rate, ``r = (x − nuisance) / σ``: N(0, 1) wherever there is
   no defect, however loud the stretch of track;
2. it divides ``r`` by the resampler's noise gain, ``√(Σ h² / up)`` for the anti-alias filter
   ``h``, so that ``r`` keeps unit variance at the detectors' rate (100 Hz at the benchmark's
   scale);
3. it streams ``r`` through the pipeline that ``railwatch detect`` runs
   (:class:`~railwatch.detection.stream.StreamingDetector`: the same resampling, windows, hop
   and merging of scores into events), scored by the window oracle's GLR test (a spike; boxes
   of 5-20 samples) with nuisance 0 and noise std 1.

Its null is known, so its event threshold follows from a false rate without training or
truth: :func:`null_threshold` streams white noise through the same pipeline. It is a ceiling for
detectors at that rate, not an exact optimum: the anti-alias filter band-limits the residual to
0.8 of the output Nyquist, and the GLR treats it as white.

With ``noise="estimated"`` it knows the clean signal only and estimates the noise level from the
residual around each sample (:func:`local_std`): the gap between the two is what not knowing the
level costs; what a detector loses beyond the second lies in the detector itself.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from railwatch.detection.stream import Event, StreamingDetector
from railwatch.detectors.api import FloatArray, Scores
from railwatch.detectors.oracle import Oracle, OracleConfig
from railwatch.errors import RailwatchError
from railwatch.recordings.prepare import Preparation, antialias_filter
from railwatch.scoring.residual import greatest_of
from railwatch.synthetic.runs import Run

OnSamples = Callable[[NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any]], None]
#: Raw samples pushed at a time (as ``detect`` reads a file block by block).
BLOCK = 200_000
#: The oracle that estimates the noise level (:func:`local_std`): reference stretches either
#: side of a sample and the guard between, in seconds of the run (the benchmark's scale: a
#: defect lasts up to 0.2 s, the noise level holds for 0.4-1.6 s).
GUARD_S, REF_S = 0.2, 0.3
#: What the oracle knows of the noise level: the run's own, or its estimate (:func:`local_std`).
NOISE = ("known", "estimated")
#: Minutes of white noise that set the oracle's event threshold (:func:`null_threshold`).
NULL_MINUTES = 100.0


class WhiteOracle(Oracle):
    """The window oracle for samples that are already whitened: nuisance 0, noise std 1."""

    needs: ClassVar[tuple[str, ...]] = ()

    def _score(self, X: FloatArray, context: dict[str, FloatArray], extras: bool) -> Scores:
        return super()._score(X, {"nuisance": np.zeros_like(X), "noise_std": np.ones_like(X)},
                              extras)


def noise_gain(up: int, down: int) -> float:
    """The std of white N(0, 1) noise after resampling by ``up / down``, averaged over the
    output phases (each output weighs every ``up``-th tap of the filter)."""
    if up == down == 1:
        return 1.0
    h = antialias_filter(up, down)
    return float(np.sqrt(np.sum(h ** 2) / up))


def whitened(run: Run, prep: Preparation, noise: str = "known") -> NDArray[np.float32]:
    """The run's residual over its noise std (n, 6), scaled to unit variance after the
    resampling of ``prep``; with ``noise="estimated"`` the std is :func:`local_std` of the
    residual instead of the true one. A one-line error if the run has no components."""
    if run.nuisance is None or run.noise_std is None:
        raise RailwatchError("the oracle needs the run's components: make it with "
                             "synthesize_run(..., components=True)")
    if noise not in NOISE:
        raise RailwatchError(f"noise must be 'known' or 'estimated', got {noise!r}")
    up, down = prep.ratio(run.fs)
    e = run.data - run.nuisance
    std = run.noise_std if noise == "known" else local_std(e, run.fs)
    return (e / std / noise_gain(up, down)).astype(np.float32)


def local_std(e: NDArray[np.floating], fs: float) -> NDArray[np.float64]:
    """Per sample and channel, the std of ``e`` (n, C) as a detector could estimate it: the root
    mean square over :data:`REF_S` on either side, :data:`GUARD_S` away (so that a defect at
    the sample does not raise it), the greater of the two sides (a greatest-of CFAR: next to a
    step in level the louder side sets it), one side at the run's ends."""
    guard, ref = max(1, round(GUARD_S * fs)), max(1, round(REF_S * fs))
    var = greatest_of(np.square(e, dtype=np.float64).T, guard, ref).T
    return np.sqrt(np.where(np.isfinite(var) & (var > 0), var, np.nanmedian(var)))


def fitted(prep: Preparation, fs: float, n_channels: int, seed: int = 0) -> WhiteOracle:
    """A :class:`WhiteOracle` for windows of ``prep`` (its null calibrated by Monte Carlo)."""
    n_steps = prep.samples(prep.window_s, fs, "the window")
    rng = np.random.default_rng(seed)
    oracle = WhiteOracle(OracleConfig(seed=seed))
    oracle.fit(rng.standard_normal((64, n_steps, n_channels)).astype(np.float32))
    return oracle


def oracle_events(run: Run, prep: Preparation | None = None, threshold: float = 1.0,
                  merge_gap_s: float = 0.5, noise: str = "known") -> list[Event]:
    """The oracle's events on ``run`` above ``threshold`` (the module docstring), streamed as
    ``detect`` streams a recording; ``noise``: as :func:`whitened`."""
    prep = prep or Preparation()
    r = whitened(run, prep, noise)
    return stream_events(iter([r]), run.fs, prep, threshold, merge_gap_s)


def stream_events(blocks: Iterator[NDArray[np.float32]], fs: float, prep: Preparation,
                  threshold: float, merge_gap_s: float = 0.5,
                  on_samples: OnSamples | None = None) -> list[Event]:
    """The oracle's events on whitened samples at ``fs`` given block by block (``on_samples``:
    as :class:`StreamingDetector`'s)."""
    stream: StreamingDetector | None = None
    events: list[Event] = []
    for block in blocks:
        if stream is None:
            oracle = fitted(prep, fs, block.shape[1])
            stream = StreamingDetector(oracle, Run.layout(fs), prep, threshold, merge_gap_s,
                                       on_samples)
        for i in range(0, len(block), BLOCK):
            events += stream.push(block[i:i + BLOCK])
    return events + (stream.close() if stream is not None else [])


def count_events(point: NDArray[np.float64], threshold: float, merge_gap: int) -> int:
    """How many events the per-sample scores ``point`` give above ``threshold``: runs of samples
    above it, merged across fewer than ``merge_gap`` quiet samples (as the stream's tracker)."""
    hits = np.flatnonzero(point > threshold)
    return int(len(hits) > 0) + int(np.sum(np.diff(hits) - 1 >= merge_gap))


def null_threshold(per_minute: float, fs: float, prep: Preparation | None = None,
                   minutes: float = NULL_MINUTES, merge_gap_s: float = 0.5,
                   seed: int = 0, noise: str = "known") -> float:
    """The oracle's event threshold for ``per_minute`` false events per minute: the lowest score
    at which ``minutes`` of white N(0, 1) noise at ``fs``, streamed as a run, give at most that
    many events per minute (its null is known: no training, no truth); ``noise="estimated"``:
    the noise whitened by its :func:`local_std`, as :func:`whitened` does."""
    prep = prep or Preparation()
    if not per_minute > 0:
        raise RailwatchError(f"the false rate must be positive, got {per_minute:g} per minute")
    if noise not in NOISE:
        raise RailwatchError(f"noise must be 'known' or 'estimated', got {noise!r}")
    rng = np.random.default_rng(seed)
    gain = noise_gain(*prep.ratio(fs))
    per_block = 60 * int(fs)
    points: list[NDArray[np.float64]] = []

    def blocks() -> Iterator[NDArray[np.float32]]:
        for _ in range(int(np.ceil(minutes))):
            z = rng.standard_normal((per_block, 6))
            yield (z / (local_std(z, fs) if noise == "estimated" else 1.0)
                   / gain).astype(np.float32)

    stream_events(blocks(), fs, prep, np.inf, merge_gap_s,
                  lambda t, point, c, x: points.append(np.array(point, np.float64)))
    point = np.concatenate(points)
    gap = max(1, round(merge_gap_s * prep.output_rate(fs)))
    allowed = per_minute * len(point) / prep.output_rate(fs) / 60.0
    lo, hi = 0.0, float(point.max())  # hi gives no event
    for _ in range(40):
        mid = (lo + hi) / 2
        lo, hi = (lo, mid) if count_events(point, mid, gap) <= allowed else (mid, hi)
    return hi
