"""Preparing a recording for a detector: the rate, window and sensor groups it is scored at,
anti-aliased resampling and windowing.

:func:`choose` picks the preparation from the layout's scale (``docs/recordings.md``). On a
real rail (``scale = "field"``, the default) a 2-10 cm defect is crossed in 1-10 ms and rings the
wheel at 50-1000 Hz: the recording keeps its rate, a window covers :data:`FIELD_WINDOW_M` of
track at the vehicle's median speed, and the axle-box channels are scored (the bogie frame and
the car body, behind the suspension, carry none of a short defect's signature but their own
motion). The benchmark's recordings (``scale = "benchmark"``, ``generate-run``) model a defect
twenty times longer: the paper's ×20 scaling, which keeps sample counts, applies, and they are
resampled to 100 Hz in 2-s windows, every channel scored (``Preparation()``).

Resampling (to ``Preparation.rate``; ``None`` keeps the file's rate) is by a rational factor
``up / down`` (2000 -> 100 Hz: 1/20; 2048 -> 100 Hz: 25/512), polyphase, behind a linear-phase
low-pass FIR filter (Kaiser window, cut-off at 80 % of the new Nyquist frequency, about 80 dB
stop-band), applied in a streaming form: the output is the same whatever the block
sizes the samples arrive in, and output sample k is the filtered signal at input time
``k · down / up`` (the filter's delay is compensated; the first and last samples are extended by
repetition). Per-channel normalisation is the detector's own, fitted on the windows of the
training recordings and saved with the model.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from fractions import Fraction
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from railwatch.errors import RailwatchError


@dataclass(frozen=True)
class Preparation:
    """How recordings become windows: the model's rate, window length and hop (seconds). The
    defaults are the benchmark's scale (:func:`choose`)."""

    rate: float | None = 100.0  # Hz after resampling; None keeps the recording's rate
    window_s: float = 2.0  # window length (the benchmark's 2 s)
    train_hop_s: float = 1.0  # hop between training windows
    detect_hop_s: float = 0.5  # hop between scored windows in detect and streaming
    #: Wheel turns on either side combed out before resampling (:mod:`railwatch.recordings.wheel`;
    #: 0: none, ``train --wheel-comb``: 2).
    wheel_turns: int = 0

    def output_rate(self, fs: float) -> float:
        return fs if self.rate is None else float(self.rate)

    def ratio(self, fs: float) -> tuple[int, int]:
        """``(up, down)``: the resampling factor ``up / down`` from ``fs`` to :attr:`rate` in
        lowest terms ((1, 1): no resampling)."""
        if self.rate is None:
            return 1, 1
        if self.rate > fs * (1 + 1e-9):
            raise RailwatchError(
                f"cannot resample {fs:g} Hz up to {self.rate:g} Hz: railwatch only lowers the "
                f"rate; choose a rate of at most {fs:g} Hz, or none")
        frac = Fraction(self.rate / fs).limit_denominator(MAX_FACTOR)
        if abs(float(frac) * fs - self.rate) > 1e-9 * self.rate:  # no drift of the time axis
            near = fs / round(fs / self.rate)  # an integer divisor of fs
            raise RailwatchError(
                f"cannot resample {fs:g} Hz to {self.rate:g} Hz: the ratio is not a fraction "
                f"with terms up to {MAX_FACTOR}; choose a rate such as {near:g} Hz, or none")
        return frac.numerator, frac.denominator

    def check(self, fs: float) -> None:
        """Every setting usable for a recording at ``fs``: one-line errors now, not later."""
        self.ratio(fs)
        window = self.samples(self.window_s, fs, "the window")
        self.samples(self.train_hop_s, fs, "the training hop")
        hop = self.samples(self.detect_hop_s, fs, "the detection hop")
        if window < 2:
            raise RailwatchError(f"a window of {self.window_s:g} s is under two samples")
        if not isinstance(self.wheel_turns, int) or not 0 <= self.wheel_turns <= 5:
            raise RailwatchError(f"wheel_turns is {self.wheel_turns!r}: a whole number of turns "
                                 "from 0 (no comb) to 5")
        if hop > window:
            raise RailwatchError(f"a detection hop of {self.detect_hop_s:g} s is longer than the "
                                 f"{self.window_s:g}-s window: samples would go unscored")

    def samples(self, seconds: float, fs: float, what: str) -> int:
        n = int(round(seconds * self.output_rate(fs)))
        if n < 1:
            raise RailwatchError(f"{what} of {seconds:g} s is shorter than one sample at "
                                 f"{self.output_rate(fs):g} Hz")
        return n

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


#: Track a field-scale window covers (m): the impact and its ringing, sixteen sleeper bays and
#: three wheel turns whatever the speed (0.5 s at 20 m/s); clipped to FIELD_WINDOW_S seconds.
FIELD_WINDOW_M = 10.0
FIELD_WINDOW_S = (0.25, 2.0)
#: The window without a speed or position column: 10 m at 20 m/s.
FIELD_WINDOW_DEFAULT_S = 0.5
#: Group names of axle-box sensors (any case): the channels scored at field scale.
AXLE_GROUPS = ("axle", "axlebox", "axle_box", "axle-box", "axleboxes", "axles")


@dataclass(frozen=True)
class Choice:
    """A preparation, the sensor groups to score, and why (a line each for the user)."""

    preparation: Preparation
    groups: tuple[str, ...]
    reasons: tuple[str, ...]


def choose(groups: tuple[str, ...], scale: str, fs: float, median_speed: float | None,
           rate: float | None | str = "auto", window_s: float | None = None,
           hop_s: float | None = None, chosen_groups: tuple[str, ...] | None = None,
           wheel_turns: int = 0) -> Choice:
    """The preparation for recordings of ``scale`` with the layout's ``groups`` at ``fs`` Hz,
    their vehicle's ``median_speed`` (m/s, None: unknown); the given ``rate`` (Hz, None: keep
    the file's; ``"auto"``), ``window_s``, ``hop_s`` (training hop; at field scale the detection
    hop is a whole window) and ``chosen_groups`` override the choice (module docstring)."""
    reasons = []
    present = tuple(dict.fromkeys(groups))
    given: float | None = None if isinstance(rate, str) else rate
    if scale == "benchmark":
        base = Preparation()
        rate = base.rate if rate == "auto" else given
        window = window_s or base.window_s
        hop = hop_s or base.train_hop_s
        detect_hop = min(base.detect_hop_s, window)
        use = chosen_groups or present
        reasons.append("benchmark scale (the layout's scale), as the paper's x20 scaling: "
                       + (f"resampled to {rate:g} Hz" if rate else f"the rate kept, {fs:g} Hz")
                       + f", {window:g}-s windows, the {', '.join(use)} channels")
    else:
        rate = given
        if window_s:
            window = window_s
        elif median_speed:
            window = float(np.clip(FIELD_WINDOW_M / median_speed, *FIELD_WINDOW_S))
            reasons.append(f"field scale: {window:.3g}-s windows, {FIELD_WINDOW_M:g} m of track "
                           f"at the median speed of {median_speed:.1f} m/s")
        else:
            window = FIELD_WINDOW_DEFAULT_S
            reasons.append(f"field scale: {window:g}-s windows ({FIELD_WINDOW_M:g} m at 20 m/s; "
                           "no speed or position column to measure the speed)")
        window = round(window * (rate or fs)) / (rate or fs)
        hop = hop_s or window / 2
        detect_hop = window  # each sample scored once: 100x real time on one core at 2 kHz
        if rate is None:
            reasons.append(f"the recording's rate kept, {fs:g} Hz (a 2-10 cm defect is crossed "
                           "in 1-10 ms at 10-30 m/s)")
        axles = tuple(g for g in present if g.lower() in AXLE_GROUPS)
        if chosen_groups:
            use = chosen_groups
        elif axles:
            use = axles
            others = [g for g in present if g not in axles]
            if others:
                reasons.append(f"scoring the {', '.join(axles)} channels; {', '.join(others)} "
                               "sit behind the suspension, where a short defect's signature "
                               "does not reach (--groups all scores them too)")
        else:
            use = present
            reasons.append(f"no axle-box group (named {AXLE_GROUPS[0]}): scoring every group; "
                           "choose the axle-box channels with --groups")
    unknown = [g for g in use if g not in present]
    if unknown:
        raise RailwatchError(f"--groups {','.join(unknown)}: the layout's groups are "
                             f"{', '.join(present)}")
    prep = Preparation(rate=rate, window_s=window, train_hop_s=hop, detect_hop_s=detect_hop,
                       wheel_turns=wheel_turns)
    return Choice(prep, tuple(use), tuple(reasons))


#: Largest term of a resampling ratio: the filter has 20 taps per unit of it.
MAX_FACTOR = 10_000


def antialias_filter(up: int, down: int = 1) -> NDArray[np.float64]:
    """Linear-phase low-pass FIR taps for resampling by ``up / down``, at the upsampled rate (odd
    length, DC gain ``up``: the zeros stuffed between input samples are made up for)."""
    m = max(up, down)
    taps = 20 * m + 1
    return up * signal.firwin(taps, 0.8 / m, window=("kaiser", 8.0))  # cut-off relative to Nyquist


class Resampler:
    """Streaming anti-aliased resampling of (n, C) blocks by a rational factor ``up / down``.

    ``push(block)`` returns the output samples that are complete; ``flush()`` the rest. Output k
    is the filtered signal at input time ``k · down / up``:
    ``y[k] = Σ_n h[k·down + D − n·up] x[n]`` with ``h`` the filter at the upsampled rate and ``D``
    its delay. Equal to one-shot filtering of the whole signal (edges extended by repetition)
    whatever the block sizes. Polyphase: outputs of equal ``k mod up`` share one set of taps
    (every ``up``-th tap of ``h``), so each such group is one strided convolution
    (``scipy.signal.upfirdn``).
    """

    def __init__(self, up: int, down: int, n_channels: int) -> None:
        self.up, self.down = up, down
        self.identity = up == down == 1
        self.h = antialias_filter(up, down) if not self.identity else np.ones(1)
        self.delay = (len(self.h) - 1) // 2  # D, at the upsampled rate
        self.n_channels = n_channels
        self.buffer = np.zeros((0, n_channels))  # input samples still needed
        self.buffer_start = 0  # input index of buffer[0] (negative while the start is padded)
        self.next_out = 0  # index of the next output sample
        self.started = False
        self.flushed = False

    def n_outputs(self, n_in: int) -> int:
        """Outputs of ``n_in`` input samples: those at input times 0 .. n_in − 1."""
        return (n_in - 1) * self.up // self.down + 1 if n_in else 0

    def clean(self, n_in: int) -> tuple[int, int]:
        """The outputs ``first .. stop − 1`` of ``n_in`` input samples whose filter read only
        the recording's own samples: the others read the edges' extension (ten outputs at
        each end from 2 kHz to 100 Hz, 0.1 s; none without resampling)."""
        if self.identity:
            return 0, n_in
        # Output k reads input n through tap k·down + D − n·up in 0 .. 2D: none before 0 when
        # k·down + D + up > 2D, none at n_in or after when k·down + D < n_in·up.
        first = -(-(self.delay - self.up + 1) // self.down)
        stop = (n_in * self.up - self.delay - 1) // self.down + 1
        return first, max(stop, first)

    def push(self, block: NDArray[Any]) -> NDArray[np.float32]:
        if self.flushed:
            raise RailwatchError("this resampler was flushed: start a new one")
        x = np.asarray(block, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self.n_channels:
            raise RailwatchError(f"expected blocks of shape (n, {self.n_channels}), got {x.shape}")
        if self.identity:
            return x.astype(np.float32)
        if not self.started and len(x):
            pad = self.delay // self.up  # input samples before 0 that output 0 reads
            self.buffer, self.buffer_start = np.repeat(x[:1], pad, axis=0), -pad
            self.started = True
        self.buffer = np.concatenate([self.buffer, x])
        return self._emit()

    def flush(self) -> NDArray[np.float32]:
        """The remaining outputs, the last sample extended forwards (once: later calls give
        nothing)."""
        if self.identity or not self.started or self.flushed:
            self.flushed = True
            return np.zeros((0, self.n_channels), np.float32)
        self.flushed = True
        n_in = self.buffer_start + len(self.buffer)  # input samples seen
        n_out = self.n_outputs(n_in)
        need = self._newest(n_out - 1) + 1 - n_in  # samples missing for the last output
        if need > 0:
            self.buffer = np.concatenate([self.buffer, np.repeat(self.buffer[-1:], need, 0)])
        return self._emit(limit=n_out)

    def _newest(self, k: int) -> int:
        """Index of the newest input sample that output ``k`` reads."""
        return (k * self.down + self.delay) // self.up

    def _emit(self, limit: int | None = None) -> NDArray[np.float32]:
        up, down = self.up, self.down
        end = self.buffer_start + len(self.buffer)  # one past the last input index held
        last = (end * up - 1 - self.delay) // down  # the last output whose inputs are all held
        if limit is not None:
            last = min(last, limit - 1)
        count = last + 1 - self.next_out
        if count <= 0:
            return np.zeros((0, self.n_channels), np.float32)
        out = np.empty((count, self.n_channels))
        zeros = np.zeros((down - 1, self.n_channels))
        padded = np.concatenate([zeros, self.buffer])  # room to align any phase (zero taps)
        for r in range(min(up, count)):  # outputs next_out + r + j·up, j = 0, 1, ...
            k = self.next_out + r
            newest = self._newest(k)
            phase = k * down + self.delay - newest * up  # h[phase + t·up] weighs x[newest − t]
            taps = self.h[phase::up]
            rel = newest - self.buffer_start + down - 1  # newest's index in ``padded``
            start = rel % down  # so that newest sits at a multiple of down in ``padded[start:]``
            # upfirdn's output i is Σ_t taps[t] seg[i·down − t]: i = (rel − start) / down + j.
            first = (rel - start) // down
            n = len(range(r, count, up))
            out[r::up] = signal.upfirdn(taps, padded[start:], up=1, down=down,
                                        axis=0)[first:first + n]
        self.next_out = last + 1
        oldest = -((self.delay - self.next_out * down) // up)  # ceil((k·down − D) / up)
        keep_from = max(oldest - self.buffer_start, 0)
        self.buffer = self.buffer[keep_from:]
        self.buffer_start += keep_from
        return out.astype(np.float32)


def resample(x: NDArray[Any], up: int, down: int) -> NDArray[np.float32]:
    """One-shot anti-aliased resampling of (n, C) by ``up / down`` (the streaming filter, one
    block)."""
    r = Resampler(up, down, x.shape[1])
    return np.concatenate([r.push(x), r.flush()])


def frame(x: NDArray[Any], window: int, hop: int, cover_end: bool = True) -> tuple[
        NDArray[np.float32], NDArray[np.int64]]:
    """Windows (K, window, C) of a signal (n, C) every ``hop`` samples, and their start indices.

    With ``cover_end`` a last window ending at the final sample is added when the hop leaves the
    tail uncovered, so every sample lies in at least one window.

    >>> w, s = frame(np.arange(10.0)[:, None], window=4, hop=3)
    >>> s.tolist(), w[-1, :, 0].tolist()
    ([0, 3, 6], [6.0, 7.0, 8.0, 9.0])
    """
    n = len(x)
    if n < window:
        raise RailwatchError(f"the recording is shorter than one window ({n} < {window} samples)")
    starts = list(range(0, n - window + 1, hop))
    if cover_end and starts[-1] + window < n:
        starts.append(n - window)
    idx = np.asarray(starts, dtype=np.int64)
    return gather_windows(x, idx, window), idx


def gather_windows(x: NDArray[Any], starts: NDArray[Any], window: int) -> NDArray[np.float32]:
    """The windows (K, window, C) of a signal (n, C) that start at ``starts``."""
    views = np.lib.stride_tricks.sliding_window_view(x, window, axis=0)  # (n−w+1, C, w)
    return np.ascontiguousarray(views[starts].transpose(0, 2, 1), dtype=np.float32)


def n_windows(n: int, window: int, hop: int) -> int:
    """How many windows :func:`frame` makes of ``n`` samples."""
    if n < window:
        return 0
    k = (n - window) // hop + 1
    return k + ((k - 1) * hop + window < n)
