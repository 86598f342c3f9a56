"""Wheel-periodic impulses taken out of a recording before the detector (``railwatch train
--wheel-comb``; docs/notes/2026-12-03-track-map-how-we-got-here.md, "The impulses out of
the signal").

A flat or out-of-round wheel strikes the rail once per turn, so its impulses repeat at the
wheel's circumference along the track, at positions of their own on every pass. Per channel:

1. **The turn**, from the recording itself: the channel on a :data:`GRID_M` grid of the
   distance travelled, per :data:`BLOCK_M` block the log power spectrum (Hann window)
   transformed back (the cepstrum), averaged over the blocks; its highest peak between
   :data:`SEARCH_M`. A channel is combed only where that peak stands :data:`GATE` robust
   standard deviations (median and MAD of the cepstrum over the range) out: on the development
   tracks' stage-8 passes half of the channels, every one on the turn or a multiple of it (which
   combs the impulses away as well); on stage-5 passes, which have no impulses, none.
2. **The comb**: each sample less the mean of the samples ±1 … ±``turns`` wheel turns away along
   the track (linear interpolation; near the recording's ends, the turns that it has). A
   defect, at one place, is left (its echoes are a quarter of it at ±1 and ±2 turns); the
   noise's variance grows by 1 / (2 · turns).

Both stream: the turn from a first read of the recording, a block at a time; the comb from a
second, its output delayed by ``turns`` wheel turns of track. The distance travelled is the sum
of the position's steps (or speed / rate), whichever way the vehicle runs.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.errors import RailwatchError
from railwatch.recordings.layout import Layout
from railwatch.recordings.readers import CHUNK_ROWS, Chunk, Recording

#: Distance grid of the cepstrum (m), its blocks (m), the range of wheel turns searched (m; a
#: railway wheel's circumference is about 2.5-3.1 m, the synthesiser's spacings 2.25-11.25 m)
#: and the gate (robust standard deviations).
GRID_M = 0.02
BLOCK_M = 200.0
SEARCH_M = (1.5, 15.0)
GATE = 5.0
NEEDS_TRAVEL = ("the wheel comb needs the distance travelled: name a position or speed column "
                "in the layout, or train without --wheel-comb")


class Travel:
    """The distance travelled at each sample of successive chunks (m, non-decreasing)."""

    def __init__(self, fs: float) -> None:
        self.fs = fs
        self.total = 0.0
        self.last: float | None = None

    def __call__(self, chunk: Chunk) -> NDArray[np.float64]:
        if chunk.position is not None:
            p = np.asarray(chunk.position, dtype=float)
            steps = np.abs(np.diff(p, prepend=p[0] if self.last is None else self.last))
            x = self.total + np.cumsum(np.nan_to_num(steps))
            self.last = float(p[-1]) if np.isfinite(p[-1]) else self.last
        elif chunk.speed is not None:
            steps = np.nan_to_num(np.abs(np.asarray(chunk.speed, dtype=float))) / self.fs
            x = self.total + np.cumsum(steps) - steps
            self.total += float(steps.sum())
            return x
        else:
            raise RailwatchError(NEEDS_TRAVEL)
        self.total = float(x[-1])
        return x


def turns_of(chunks: Iterable[Chunk], fs: float, n_channels: int) -> list[float | None]:
    """Per channel, the wheel's turn in m (module docstring, 1.), or None where the cepstrum
    has no peak past the gate (or the recording is shorter than one block)."""
    return [turn if z >= GATE else None for turn, z in cepstral_peaks(chunks, fs, n_channels)]


def cepstral_peaks(chunks: Iterable[Chunk], fs: float, n_channels: int,
                   ) -> list[tuple[float, float]]:
    """Per channel, the highest peak of the cepstrum over distance within :data:`SEARCH_M`
    (m) and how far it stands out (robust z: median and MAD over the range); ``(nan, 0)`` for a
    recording shorter than one block."""
    travel = Travel(fs)
    block = int(round(BLOCK_M / GRID_M))
    window = np.hanning(block)
    total = np.zeros((n_channels, block))
    blocks = 0
    xs: list[NDArray[np.float64]] = []
    vs: list[NDArray[Any]] = []
    start = 0.0
    for chunk in chunks:
        xs.append(travel(chunk))
        vs.append(np.asarray(chunk.data, dtype=float))
        if xs[-1][-1] - start < BLOCK_M:
            continue
        x, v = np.concatenate(xs), np.concatenate(vs)
        while x[-1] - start >= BLOCK_M:
            grid = start + GRID_M * np.arange(block)
            for c in range(n_channels):
                u = np.interp(grid, x, v[:, c])
                power = np.abs(np.fft.rfft((u - u.mean()) * window)) ** 2
                total[c] += np.fft.irfft(np.log(power + 1e-12 * power.max() + 1e-300), block)
            blocks += 1
            start += BLOCK_M
        keep = max(int(np.searchsorted(x, start)) - 1, 0)
        xs, vs = [x[keep:]], [v[keep:]]
    if not blocks:
        return [(float("nan"), 0.0)] * n_channels
    q = GRID_M * np.arange(block)
    inside = (q >= SEARCH_M[0]) & (q <= SEARCH_M[1])
    out = []
    for c in range(n_channels):
        values = total[c, inside]
        k = int(np.argmax(values))
        med = np.median(values)
        spread = 1.4826 * np.median(np.abs(values - med))  # MAD_TO_STD: scoring sits above
        out.append((float(q[inside][k]), float((values[k] - med) / spread) if spread > 0
                    else 0.0))
    return out


class Comb:
    """The comb of module docstring, 2., on successive chunks: ``push`` returns the chunks
    whose samples are done (every turn ahead of them seen), ``close`` the rest; the samples
    come out in order, with their time, speed and position columns, whatever the chunking."""

    def __init__(self, turns: list[float | None], n_turns: int, fs: float) -> None:
        self.turns = turns
        self.offsets = [k for k in range(-n_turns, n_turns + 1) if k]
        self.reach = n_turns * max((t for t in turns if t is not None), default=0.0)
        self.travel = Travel(fs)
        self.x = np.zeros(0)
        self.data = np.zeros((0, len(turns)))
        self.columns: dict[str, NDArray[Any] | None] = {}
        self.done = 0  # buffered samples already sent out
        self.first: float | None = None  # distance at the recording's first sample
        self.sent = 0  # samples sent out in all

    def push(self, chunk: Chunk) -> list[Chunk]:
        if not len(chunk):
            return []
        x = self.travel(chunk)
        if self.first is None:
            self.first = float(x[0])
        self.x = np.concatenate([self.x, x])
        self.data = np.concatenate([self.data, np.asarray(chunk.data, dtype=float)])
        for name in ("time", "speed", "position"):
            value = getattr(chunk, name)
            old = self.columns.get(name)
            self.columns[name] = None if value is None else (
                value if old is None else np.concatenate([old, value]))
        ready = int(np.searchsorted(self.x, self.x[-1] - self.reach, side="right"))
        return self._send(ready)

    def close(self) -> list[Chunk]:
        return self._send(len(self.x))

    def _column(self, name: str, part: slice) -> NDArray[Any] | None:
        value = self.columns.get(name)
        return None if value is None else value[part]

    def _send(self, upto: int) -> list[Chunk]:
        if upto <= self.done:
            return []
        part = slice(self.done, upto)
        x, out = self.x[part], self.data[part].copy()
        lo, hi = self.first or 0.0, float(self.x[-1])
        for c, turn in enumerate(self.turns):
            if turn is None:
                continue
            total, count = np.zeros(len(x)), np.zeros(len(x))
            for k in self.offsets:
                at = x + k * turn
                ok = (at >= lo) & (at <= hi)
                total[ok] += np.interp(at[ok], self.x, self.data[:, c])
                count += ok
            out[:, c] -= np.where(count > 0, total / np.maximum(count, 1), 0.0)
        time, speed, position = (self._column(n, part) for n in ("time", "speed", "position"))
        chunk = Chunk(self.sent, out.astype(np.float32), time, speed, position)
        self.sent += upto - self.done
        self.done = upto
        # Keep the turns behind the first sample still to come (and one sample more).
        keep = max(int(np.searchsorted(self.x, self.x[self.done] - self.reach)) - 1, 0) \
            if self.done < len(self.x) else max(len(self.x) - 1, 0)
        keep = min(keep, self.done)
        self.x, self.data = self.x[keep:], self.data[keep:]
        self.columns = {n: None if v is None else v[keep:] for n, v in self.columns.items()}
        self.done -= keep
        return [chunk]


def comb_chunks(chunks: Iterable[Chunk], turns: list[float | None], n_turns: int,
                fs: float) -> Iterator[Chunk]:
    """``chunks`` with each channel's ``turns`` combed out (:class:`Comb`)."""
    comb = Comb(turns, n_turns, fs)
    for chunk in chunks:
        yield from comb.push(chunk)
    yield from comb.close()


def check_layout(layout: Layout) -> None:
    """A one-line error unless ``layout`` names a position or speed column (the comb needs the
    distance travelled)."""
    if not (layout.position or layout.speed):
        raise RailwatchError(NEEDS_TRAVEL)


def recording_turns(recording: Recording, rows: int = CHUNK_ROWS) -> list[float | None]:
    """Each channel's wheel turn in ``recording`` (:func:`turns_of`, one read of the file)."""
    layout = recording.layout
    check_layout(layout)
    return turns_of(recording.chunks(rows), layout.fs, len(layout.channels))


def combed(recording: Recording, n_turns: int, rows: int = CHUNK_ROWS,
           turns: list[float | None] | None = None) -> Iterator[Chunk]:
    """The chunks of ``recording`` with each channel's wheel turns combed out (module
    docstring): ``turns`` as :func:`recording_turns` finds them (a first read) unless given."""
    if turns is None:
        turns = recording_turns(recording, rows)
    return comb_chunks(recording.chunks(rows), turns, n_turns, recording.layout.fs)
