"""Window -> timeline merging, events, and the streaming scorer against batch computation."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railwatch.detection.stream import (
    EventTracker,
    StreamingDetector,
    assign_centres,
    merge_max,
)
from railwatch.detectors import create
from railwatch.errors import RailwatchError
from railwatch.recordings.layout import Layout
from railwatch.recordings.prepare import Preparation, frame, resample


def merge_by_loop(n: int, starts: Sequence[int], values: np.ndarray, guard: int = 0,
                  last: int | None = None) -> np.ndarray:
    """Per sample of ``n``, the maximum of the windows' steps (``values`` (K, T, ...) at
    ``starts``) but for each window's first and last ``guard`` ones; a window at sample 0
    keeps its first steps, one that ends at ``last`` its last ones."""
    width = values.shape[1]
    out = np.full((n, *values.shape[2:]), -np.inf)
    for s, v in zip(starts, values, strict=True):
        for j in range(width):
            if (s == 0 or j >= guard) and (s + width == last or j < width - guard):
                out[s + j] = np.maximum(out[s + j], v[j])
    return out


@given(st.integers(1, 30), st.integers(1, 10), st.integers(0, 4), st.integers(0, 2**31))
def test_merge_max_equals_a_loop(n_windows: int, width: int, guard: int, seed: int) -> None:
    """Each window's steps merge by their maximum, but for its first and last ``guard`` ones;
    a window at the first sample keeps its first steps, one at the last its last ones."""
    rng = np.random.default_rng(seed)
    starts = np.sort(rng.integers(0, 40, n_windows))
    values = rng.normal(size=(n_windows, width, 2))
    acc = np.full((40 + width, 2), -np.inf)
    last = int(starts[-1]) + width
    merge_max(acc, values, starts, 0, guard, last)
    np.testing.assert_array_equal(acc, merge_by_loop(40 + width, starts.tolist(), values, guard,
                                                     last))


def owner_by_loop(n: int, starts: list[int], width: int, hop: int) -> list[int]:
    """Per sample, the window whose central ``hop`` samples hold it (``frame``'s windows: every
    ``hop``, and a last one ending at the last sample); the first window also owns the samples
    before its centre, the last one those after the regular windows' centres."""
    lo = (width - hop) // 2
    regular = [s for s in starts if s % hop == 0]
    owner = []
    for i in range(n):
        k = next((w for w, s in enumerate(regular) if s + lo <= i < s + lo + hop), None)
        if k is None:
            k = 0 if i < lo else len(starts) - 1
        owner.append(k)
    return owner


@given(st.integers(4, 30), st.integers(1, 4), st.integers(0, 12), st.integers(0, 2**31))
def test_assign_centres_equals_a_loop(width: int, hop_part: int, extra: int, seed: int) -> None:
    """Each sample takes the score of the window it is most central in."""
    hop = max(1, width * hop_part // 4)
    n = width + extra
    starts = list(range(0, n - width + 1, hop))
    if starts[-1] + width < n:
        starts.append(n - width)
    values = np.random.default_rng(seed).normal(size=(len(starts), width, 2))
    acc = np.full((n, 2), -np.inf)
    assert assign_centres(acc, values, np.asarray(starts), 0, 0, hop, last_to=n) == n
    owner = owner_by_loop(n, starts, width, hop)
    brute = np.array([values[owner[i], i - starts[owner[i]]] for i in range(n)])
    np.testing.assert_array_equal(acc, brute)


@settings(max_examples=40)
@given(st.lists(st.integers(1, 50), min_size=1, max_size=12), st.integers(0, 2**31),
       st.integers(1, 8))
def test_events_do_not_depend_on_block_sizes(sizes: list[int], seed: int, gap: int) -> None:
    rng = np.random.default_rng(seed)
    n = sum(sizes)
    point = np.where(rng.random(n) < 0.15, 3.0 + rng.random(n), rng.random(n))
    channel = rng.random((n, 3))
    time = np.arange(n) / 10.0

    def run(blocks: list[int]) -> list:  # type: ignore[type-arg]
        tracker = EventTracker(2.0, gap, ("a", "b", "c"), ("g", "g", "h"))
        events, i = [], 0
        for b in blocks:
            events += tracker.feed(point[i:i + b], channel[i:i + b], time[i:i + b], None, 0.1)
            i += b
        return events + tracker.close()

    one = run([n])
    assert run(sizes) == one
    # Brute force: maximal runs above the threshold, merged across fewer than `gap` quiet samples.
    hits = np.flatnonzero(point > 2.0)
    groups = np.split(hits, np.flatnonzero(np.diff(hits) - 1 >= gap) + 1) if len(hits) else []
    assert [(e.start_s, e.end_s) for e in one] == [
        (time[g[0]], time[g[-1]] + 0.1) for g in groups]
    for e, g in zip(one, groups, strict=True):
        peak = g[np.argmax(point[g])]
        assert e.peak_s == time[peak] and e.channel == "abc"[int(np.argmax(channel[peak]))]


def recording(fs: float) -> np.ndarray:
    """30 s of two channels at ``fs``: a spike at 7.5 s on x, an offset from 20 s on y."""
    rng = np.random.default_rng(0)
    t = np.arange(int(30 * fs)) / fs
    raw = np.stack([np.sin(2 * np.pi * 3 * t), np.cos(2 * np.pi * 1 * t)], 1)
    raw = raw + 0.1 * rng.normal(size=raw.shape)
    raw[(t >= 7.5) & (t < 7.52), 0] += 4.0
    raw[(t >= 20.0) & (t < 20.15), 1] -= 2.0
    return raw.astype(np.float32)


@pytest.fixture(scope="module")
def tiny() -> tuple[object, Layout, Preparation, np.ndarray]:
    """A tiny CNN autoencoder on 50-sample windows at 100 Hz (recorded at 200 Hz)."""
    raw = recording(200.0)
    layout = Layout(fs=200.0, channels=("x", "y"), groups=("axle", "body"))
    prep = Preparation(rate=100.0, window_s=0.5, train_hop_s=0.25, detect_hop_s=0.2)
    windows, _ = frame(resample(raw, 1, 2), 50, 25)
    det = create("cnn-ae", {"epochs": 2, "widths": (4, 4), "progress": False}).fit(windows)
    return det, layout, prep, raw


@pytest.mark.parametrize(("fs", "up", "down", "guard"),
                         [(200.0, 1, 2, 0), (240.0, 5, 12, 0), (200.0, 1, 2, 10)])
def test_streaming_equals_brute_force_batch(tiny, fs: float, up: int,  # type: ignore[no-untyped-def]
                                            down: int, guard: int, monkeypatch) -> None:
    """Block by block as in one batch; with a detector's ``edge_guard``, each window's first and
    last steps left to the windows that overlap them, and still every sample scored."""
    det, layout, prep, _ = tiny
    monkeypatch.setattr(type(det), "edge_guard", guard)
    raw = recording(fs)  # 240 Hz: a rational resampling factor (5 / 12)
    layout = Layout(fs=fs, channels=layout.channels, groups=layout.groups)
    rng = np.random.default_rng(3)
    traces: list[np.ndarray] = []
    centres: list[np.ndarray] = []
    stream = StreamingDetector(det, layout, prep, threshold=float(det.threshold_) * 0.5,
                               on_samples=lambda t, p, c, pos: traces.append(np.c_[t, p]),
                               on_centres=lambda t, c, pos: centres.append(c))
    events, i = [], 0
    while i < len(raw):
        n = int(rng.integers(1, 300))
        events += stream.push(raw[i:i + n])
        i += n
    events += stream.close()
    got = np.concatenate(traces)

    # Batch: resample everything, frame (every 20 samples, tail covered), merge by a loop.
    signal = resample(raw, up, down)
    assert len(signal) == 3000
    windows, starts = frame(signal, 50, 20)
    scores = det.score(windows).point  # type: ignore[attr-defined]
    brute = merge_by_loop(len(signal), starts.tolist(), scores, guard, len(signal))
    assert np.isfinite(brute).all()
    np.testing.assert_allclose(got[:, 0], np.arange(len(signal)) / 100.0)
    np.testing.assert_allclose(got[:, 1], brute, rtol=1e-5, atol=1e-5)
    # The central profile: each sample's channel scores from the window it is most central in.
    channel = det.score(windows).channel  # type: ignore[attr-defined]
    owner = owner_by_loop(len(signal), starts.tolist(), 50, 20)
    central = np.array([channel[owner[i], i - starts[owner[i]]] for i in range(len(signal))])
    np.testing.assert_allclose(np.concatenate(centres), central, rtol=1e-5, atol=1e-5)

    again = StreamingDetector(det, layout, prep, threshold=float(det.threshold_) * 0.5)
    assert [e.peak_s for e in again.push(raw) + again.close()] == [e.peak_s for e in events]
    assert any(abs(e.peak_s - 7.5) < 0.1 and e.channel == "x" for e in events)  # the spike


def test_no_events_where_the_filter_read_past_the_ends(tiny) -> None:  # type: ignore[no-untyped-def]
    """Jolts in the recording's first and last samples, where the resampling filter reads the
    edges' extension: their scores stay in the trace, but raise no event; the spike at 7.5 s
    still does."""
    det, layout, prep, raw = tiny
    x = raw.copy()
    x[:3] += 40.0
    x[-3:] -= 40.0
    trace: list[np.ndarray] = []
    stream = StreamingDetector(det, layout, prep, threshold=float(det.threshold_),
                               on_samples=lambda t, p, c, pos: trace.append(p))
    events = stream.push(x) + stream.close()
    first, stop = stream.resampler.clean(len(x))
    assert (first, stop) == (10, 2990)  # 200 -> 100 Hz: 0.1 s at each end
    scores = np.concatenate(trace)
    assert scores[:first].max() > det.threshold_ and scores[stop:].max() > det.threshold_
    assert all(first / 100 <= e.start_s and e.end_s <= (stop - 1) / 100 for e in events)
    assert any(abs(e.peak_s - 7.5) < 0.1 for e in events)


def test_stream_errors(tiny) -> None:  # type: ignore[no-untyped-def]
    det, layout, prep, raw = tiny
    with pytest.raises(RailwatchError, match="names 3 channels but the model was trained on 2"):
        StreamingDetector(det, Layout(fs=200.0, channels=("a", "b", "c"), groups=("g",) * 3),
                          prep)
    with pytest.raises(RailwatchError, match="model takes 50"):
        StreamingDetector(det, layout, Preparation(rate=100.0, window_s=1.0))
    with pytest.raises(RailwatchError, match="longer than the"):
        StreamingDetector(det, layout, Preparation(rate=100.0, window_s=0.5, detect_hop_s=1.0))
    stream = StreamingDetector(det, layout, prep)
    with pytest.raises(RailwatchError, match=r"shape \(n, 2\)"):
        stream.push(raw[:10, :1])
    bad = raw[:10].copy()
    bad[3, 1] = np.nan
    with pytest.raises(RailwatchError, match="non-finite"):
        stream.push(bad)
    short = StreamingDetector(det, layout, prep)
    short.push(raw[:20])
    with pytest.raises(RailwatchError, match="shorter than one window"):
        short.close()
    assert short.close() == []  # closed: the padded tail is not scored again
    with pytest.raises(RailwatchError, match="closed"):
        short.push(raw[:20])


def test_the_noise_floor_travels_with_the_windows() -> None:
    """A detector that uses the noise floor gets, in the stream, the floor of each window's
    samples: block by block the same scores as the resampled recording and its floor framed at
    once (2 kHz to 100 Hz)."""
    from railwatch.recordings.floor import NOISE_FLOOR, noise_floor

    raw = recording(2000.0)
    layout = Layout(fs=2000.0, channels=("x", "y"), groups=("axle", "body"))
    prep = Preparation(rate=100.0, window_s=1.0, train_hop_s=0.5, detect_hop_s=0.5)
    signal, floor = resample(raw, 1, 20), noise_floor(raw, 1, 20)
    assert len(floor) == len(signal)
    windows, starts = frame(signal, 100, 50)
    floors = frame(floor, 100, 50)[0]
    det = create("nuisance-glr", {"null_windows": 2000}).fit(windows, {NOISE_FLOOR: floors})
    traces: list[np.ndarray] = []
    stream = StreamingDetector(det, layout, prep, threshold=np.inf,
                               on_samples=lambda t, p, c, pos: traces.append(p))
    rng, i = np.random.default_rng(5), 0
    while i < len(raw):
        n = int(rng.integers(1, 4000))
        stream.push(raw[i:i + n])
        i += n
    stream.close()
    point = det.score(windows, {NOISE_FLOOR: floors}).point
    assert det.edge_guard == 20  # the detector's guard
    brute = merge_by_loop(len(signal), starts.tolist(), point, det.edge_guard, len(signal))
    np.testing.assert_allclose(np.concatenate(traces), brute, rtol=1e-4, atol=1e-4)
