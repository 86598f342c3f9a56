"""Preparing a recording for a detector: anti-aliased resampling and windowing.

The paper scales its 2000 Hz field data by ×20 to the benchmark's 100 Hz; railwatch does the same
by default (``Preparation.rate`` = 100 Hz, or ``None`` to keep the file's rate). Resampling is an
integer decimation behind a linear-phase low-pass FIR filter (Kaiser window, cut-off at 80 % of
the new Nyquist frequency, about 80 dB stop-band), applied in a streaming form: the output is the
same whatever the block sizes the samples arrive in, and output sample k is the filtered signal at
input sample ``k · q`` (the filter's delay is compensated; the first and last samples are
extended by repetition). Per-channel normalisation is the detector's own, fitted on the windows of
the training recordings and saved with the model.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from railwatch.errors import RailwatchError


@dataclass(frozen=True)
class Preparation:
    """How recordings become windows: the model's rate, window length and hop (seconds)."""

    rate: float | None = 100.0  # Hz after resampling; None keeps the recording's rate
    window_s: float = 2.0  # window length (the benchmark's 2 s)
    train_hop_s: float = 1.0  # hop between training windows
    detect_hop_s: float = 0.5  # hop between scored windows in detect and streaming

    def output_rate(self, fs: float) -> float:
        return fs if self.rate is None else float(self.rate)

    def factor(self, fs: float) -> int:
        """The integer decimation factor from ``fs`` to :attr:`rate` (1: no resampling)."""
        if self.rate is None:
            return 1
        q = fs / self.rate
        if q < 1 - 1e-9 or abs(q - round(q)) > 1e-6:
            raise RailwatchError(
                f"cannot resample {fs:g} Hz to {self.rate:g} Hz: the recording's rate must be an "
                f"integer multiple of the target; choose a rate that divides {fs:g} Hz, or none")
        return int(round(q))

    def check(self, fs: float) -> None:
        """Every setting usable for a recording at ``fs``: one-line errors now, not later."""
        self.factor(fs)
        window = self.samples(self.window_s, fs, "the window")
        self.samples(self.train_hop_s, fs, "the training hop")
        hop = self.samples(self.detect_hop_s, fs, "the detection hop")
        if window < 2:
            raise RailwatchError(f"a window of {self.window_s:g} s is under two samples")
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


def antialias_filter(q: int) -> NDArray[np.float64]:
    """Linear-phase low-pass FIR taps for decimation by ``q`` (odd length, unit DC gain)."""
    taps = 20 * q + 1
    return signal.firwin(taps, 0.8 / q, window=("kaiser", 8.0))  # cut-off relative to Nyquist


class Decimator:
    """Streaming anti-aliased decimation of (n, C) blocks by an integer factor.

    ``push(block)`` returns the output samples that are complete; ``flush()`` the rest. Output k
    corresponds to input sample k · q. Equal to one-shot filtering of the whole signal (edges
    extended by repetition) whatever the block sizes.
    """

    def __init__(self, q: int, n_channels: int) -> None:
        self.q = q
        self.h = antialias_filter(q) if q > 1 else np.ones(1)
        self.delay = (len(self.h) - 1) // 2
        self.n_channels = n_channels
        self.buffer = np.zeros((0, n_channels))  # input samples still needed
        self.buffer_start = 0  # input index of buffer[0] (negative while the start is padded)
        self.next_out = 0  # index of the next output sample
        self.started = False
        self.flushed = False

    def push(self, block: NDArray[Any]) -> NDArray[np.float32]:
        if self.flushed:
            raise RailwatchError("this resampler was flushed: start a new one")
        x = np.asarray(block, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self.n_channels:
            raise RailwatchError(f"expected blocks of shape (n, {self.n_channels}), got {x.shape}")
        if self.q == 1:
            return x.astype(np.float32)
        if not self.started and len(x):
            pad = np.repeat(x[:1], self.delay, axis=0)  # extend the first sample backwards
            self.buffer, self.buffer_start, self.started = pad, -self.delay, True
        self.buffer = np.concatenate([self.buffer, x])
        return self._emit()

    def flush(self) -> NDArray[np.float32]:
        """The remaining outputs, the last sample extended forwards (once: later calls give
        nothing)."""
        if self.q == 1 or not self.started or self.flushed:
            self.flushed = True
            return np.zeros((0, self.n_channels), np.float32)
        self.flushed = True
        n_in = self.buffer_start + len(self.buffer)  # input samples seen
        n_out = -(-n_in // self.q)
        need = (n_out - 1) * self.q + self.delay + 1 - n_in  # samples missing for the last one
        if need > 0:
            self.buffer = np.concatenate([self.buffer, np.repeat(self.buffer[-1:], need, 0)])
        return self._emit(limit=n_out)

    def _emit(self, limit: int | None = None) -> NDArray[np.float32]:
        end = self.buffer_start + len(self.buffer)  # one past the last input index held
        # Output k needs inputs k·q − delay .. k·q + delay.
        last = (end - 1 - self.delay) // self.q
        if limit is not None:
            last = min(last, limit - 1)
        if last < self.next_out:
            return np.zeros((0, self.n_channels), np.float32)
        lo = self.next_out * self.q - self.delay - self.buffer_start
        hi = last * self.q + self.delay + 1 - self.buffer_start
        seg = self.buffer[lo:hi]  # (m, C)
        # Polyphase: upfirdn's output i + (len(h) − 1) / q is Σ_j h[j] seg[i·q + len(h) − 1 − j],
        # i.e. Σ_j h[j] x[k·q + delay − j] for output k = next_out + i.
        first = (len(self.h) - 1) // self.q
        out = signal.upfirdn(self.h, seg, up=1, down=self.q, axis=0)[
            first:first + last + 1 - self.next_out]
        self.next_out = last + 1
        keep_from = self.next_out * self.q - self.delay - self.buffer_start
        self.buffer = self.buffer[keep_from:]
        self.buffer_start += keep_from
        return out.astype(np.float32)


def decimate(x: NDArray[Any], q: int) -> NDArray[np.float32]:
    """One-shot anti-aliased decimation of (n, C) by ``q`` (the streaming filter, one block)."""
    d = Decimator(q, x.shape[1])
    return np.concatenate([d.push(x), d.flush()])


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
