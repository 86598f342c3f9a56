"""The noise floor: how loud the recording's broadband noise is at each resampled sample, measured
in the band that the resampling throws away.

A recording at 2 kHz resampled to 100 Hz keeps 0-40 Hz; everything above is filtered out. In
that band the running vibration, the bursts of rough track and the wheel's impulses at the
benchmark's scale have next to no energy, while white noise has 95 % of its own. The second
difference ``(x_{i+1} − 2 x_i + x_{i−1}) / √6`` of the raw samples is therefore almost pure
noise: its mean square is the noise's variance (a sinusoid of frequency f keeps
``(2 π f / fs)² / √6`` of its amplitude: 0.03 % at 25 Hz in 2 kHz). The floor of resampled
sample k is that mean square over the raw samples nearest to k (``down / up`` of them: 20 from
2 kHz to 100 Hz), so a detector that divides by it sees the noise level step where it steps,
with twenty times more samples to measure it than the resampled window holds
(``docs/notes/2026-12-06-a-noise-floor-and-a-harmonic-model.md``).

It is a property of the benchmark's scale, where a recording is resampled to well below its
rate. At field scale a recording is kept at its own rate: there is no band to throw away, and
no floor (detectors then estimate the level from the window itself).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

#: Name of the floor among a detector's side arrays (``Detector.uses``).
NOISE_FLOOR = "noise_floor"


class NoiseFloor:
    """Streaming noise floor of (n, C) blocks resampled by ``up / down`` (module docstring).

    ``push(block)`` returns the floor (k, C) of the resampled samples that no later raw sample
    can change; ``flush()`` the rest, up to the resampler's last output
    (:meth:`railwatch.recordings.prepare.Resampler.n_outputs`). Raw sample ``i`` belongs to
    resampled sample ``⌊i · up / down + 1/2⌋``, the one nearest in time (the later on a tie;
    raw samples after the last resampled one belong to it). Whatever the block sizes, the floor
    is the same as of the whole recording at once.
    """

    def __init__(self, up: int, down: int, n_channels: int) -> None:
        self.up, self.down = up, down
        self.tail = np.zeros((0, n_channels))  # the last two raw samples
        self.n_in = 0  # raw samples received
        self.next_out = 0  # first resampled sample not yet returned
        self.sums = np.zeros((0, n_channels))  # from next_out on
        self.counts = np.zeros(0)
        self.last = np.full(n_channels, np.nan)  # the last floor returned (fills gaps)

    def owner(self, i: NDArray[Any] | int) -> NDArray[np.int64]:
        """The resampled sample that raw samples ``i`` belong to."""
        return (2 * np.asarray(i, dtype=np.int64) * self.up + self.down) // (2 * self.down)

    def push(self, block: NDArray[Any]) -> NDArray[np.float64]:
        full = np.concatenate([self.tail, np.asarray(block, dtype=np.float64)])
        first = self.n_in - len(self.tail)  # raw index of full[0]
        self.n_in += len(block)
        if len(full) >= 3:
            d2 = (full[2:] - 2 * full[1:-1] + full[:-2]) / np.sqrt(6.0)  # at raw first+1 ..
            k = self.owner(np.arange(first + 1, first + 1 + len(d2))) - self.next_out
            size = int(k[-1]) + 1
            if size > len(self.counts):
                grow = size - len(self.counts)
                self.sums = np.concatenate([self.sums, np.zeros((grow, self.sums.shape[1]))])
                self.counts = np.concatenate([self.counts, np.zeros(grow)])
            for c in range(full.shape[1]):
                self.sums[:, c] += np.bincount(k, d2[:, c] ** 2, minlength=len(self.counts))
            self.counts += np.bincount(k, minlength=len(self.counts))
        self.tail = full[-2:]
        # The next second difference sits at raw n_in − 1: outputs before its owner are done,
        # but for the last one so far, which takes the raw samples after it if the recording
        # ends (:meth:`flush`).
        return self._emit(min(int(self.owner(self.n_in - 1)),
                              (self.n_in - 1) * self.up // self.down))

    def flush(self) -> NDArray[np.float64]:
        n_out = (self.n_in - 1) * self.up // self.down + 1 if self.n_in else 0
        last = n_out - 1 - self.next_out  # the last resampled sample, in the pending rows
        if 0 <= last < len(self.counts) - 1:  # raw samples after it: nearest to it
            self.sums[last] += self.sums[last + 1:].sum(axis=0)
            self.counts[last] += self.counts[last + 1:].sum()
            self.sums, self.counts = self.sums[:last + 1], self.counts[:last + 1]
        return self._emit(n_out)

    def _emit(self, upto: int) -> NDArray[np.float64]:
        k = max(0, upto - self.next_out)
        if len(self.counts) < k:  # outputs no raw sample's difference reached (the ends)
            grow = k - len(self.counts)
            self.sums = np.concatenate([self.sums, np.zeros((grow, self.sums.shape[1]))])
            self.counts = np.concatenate([self.counts, np.zeros(grow)])
        with np.errstate(invalid="ignore", divide="ignore"):
            out = self.sums[:k] / self.counts[:k, None]
        gap = self.counts[:k] == 0
        if gap.any():  # a gap takes the floor before it (after it at the very start)
            rows = np.arange(k)
            before = np.maximum.accumulate(np.where(gap, -1, rows))  # last row with a floor
            out[gap] = np.where(before[gap, None] >= 0, out[np.maximum(before[gap], 0)],
                                self.last)
        if (~gap).any():
            self.last = out[np.flatnonzero(~gap)[-1]].copy()
        if k and np.isnan(out).any():
            valid = out[~np.isnan(out).any(axis=1)]
            out[np.isnan(out).any(axis=1)] = valid[0] if len(valid) else 0.0
        self.sums, self.counts = self.sums[k:], self.counts[k:]
        self.next_out += k
        return out


def noise_floor(x: NDArray[Any], up: int, down: int) -> NDArray[np.float64]:
    """The floor (n_out, C) of a whole recording ``x`` (n, C): :class:`NoiseFloor` at once."""
    meter = NoiseFloor(up, down, x.shape[1])
    return np.concatenate([meter.push(x), meter.flush()])
