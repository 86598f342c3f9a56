"""Streaming detection: raw samples in, events out, with bounded memory and latency.

:class:`StreamingDetector` takes blocks of raw samples as they arrive (any sizes), resamples them
(:class:`~railwatch.recordings.prepare.Resampler`), scores every complete window (``window``
samples every ``hop``), merges the windows' per-step scores into one score per sample (the maximum
over the windows that cover it, so a sample's score exceeds the instance threshold exactly when
some window containing it would be flagged), and turns runs of samples above the detector's fitted
threshold into :class:`Event` objects. A detector whose scores are not to be trusted at a window's
edges says how many steps (its ``edge_guard``; nuisance-glr's: a burst cut by the edge looks
like a defect there): the merge leaves each window's first and last steps to the windows that
hold them further in, as far as the hop lets every sample keep one (the recording's first and
last samples keep the only window they have). The outputs whose resampling filter read past
the recording's ends (:meth:`~railwatch.recordings.prepare.Resampler.clean`: 0.1 s at each end
from 2 kHz to 100 Hz) raise no event: the filter saw the edge's extension there, not the rail
(the first output carries 2.8 times the noise of the others, and on the benchmark's runs a
false event at t = 0; their scores stay in the trace and the track map's profile).
``railwatch detect`` is this class fed one file
block by block, so batch and streaming detection give the same events by construction (a test
feeds random block sizes; the per-sample scores agree to float rounding, as windows may be
batched differently).

Latency: a sample's score is final once no later window can cover it, i.e. one window (plus up to
one hop) after it arrives; an event is emitted when ``merge_gap_s`` of quiet samples have followed
it; the resampling filter adds its delay (10 output periods: 0.1 s at 100 Hz). With the defaults
(2-s windows, 0.5-s hop, 0.5-s merge gap) an event leaves at most about 3.1 s of recording after
the defect.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.detectors.api import Detector
from railwatch.errors import RailwatchError
from railwatch.recordings.floor import NOISE_FLOOR, NoiseFloor
from railwatch.recordings.layout import Layout
from railwatch.recordings.prepare import Preparation, Resampler, gather_windows
from railwatch.recordings.readers import Chunk


@dataclass(frozen=True)
class Event:
    """One detected defect candidate."""

    start_s: float  # time of the first sample above the threshold
    end_s: float  # time just after the last sample above the threshold
    peak_s: float  # time of the highest score
    channel: str  # the channel with the highest score at the peak
    group: str  # its sensor group
    score: float  # the peak score
    threshold: float
    position_m: float | None = None  # track position at the peak (position or integrated speed)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def merge_max(acc: NDArray[Any], values: NDArray[Any], starts: NDArray[Any], offset: int,
              guard: int = 0, last: int | None = None) -> None:
    """In place: ``acc[s − offset + j] = max(acc[...], values[w, j])`` for window w at start s,
    leaving out each window's first and last ``guard`` steps (a window that begins at sample 0,
    the recording's first, keeps its first steps; one that ends at sample ``last``, the
    recording's last, keeps its last ones).

    ``acc`` holds per-sample scores (n, ...) from sample ``offset``; ``values`` (K, T, ...) the
    windows' per-step scores.

    >>> acc = np.full(6, -np.inf)
    >>> merge_max(acc, np.array([[1.0, 5.0, 1.0], [2.0, 2.0, 2.0]]), np.array([0, 2]), 0)
    >>> acc.tolist()
    [1.0, 5.0, 2.0, 2.0, 2.0, -inf]
    """
    n_steps = values.shape[1]
    for w, start in enumerate(np.asarray(starts).tolist()):  # K slices: no scatter needed
        lo = 0 if start == 0 else guard
        hi = n_steps if start + n_steps == last else n_steps - guard
        s = start - offset
        if hi > lo:
            np.maximum(acc[s + lo:s + hi], values[w, lo:hi], out=acc[s + lo:s + hi])


def assign_centres(acc: NDArray[Any], values: NDArray[Any], starts: NDArray[Any], offset: int,
                   owned: int, hop: int, last_to: int | None = None) -> int:
    """In place: each sample from ``owned`` on takes the per-step score of the window it is
    most central in. Window ``w`` (start ``s``, in order) scores the samples from where the
    previous one stopped to ``s + (T + hop) // 2`` (the last window, when ``last_to`` is given,
    to ``last_to``): with windows every ``hop`` samples that is its central ``hop`` samples,
    and the first window also scores the recording's first samples. ``acc`` holds per-sample
    scores (n, ...) from sample ``offset``; ``values`` (K, T, ...) the windows' per-step
    scores. Returns the sample up to which scores are assigned.

    >>> acc = np.full(8, -np.inf)
    >>> assign_centres(acc, np.array([[1.0, 1, 1, 1], [2.0, 2, 2, 2]]), np.array([0, 2]), 0,
    ...                0, 2, last_to=6)
    6
    >>> acc.tolist()
    [1.0, 1.0, 1.0, 2.0, 2.0, 2.0, -inf, -inf]
    """
    n_steps = values.shape[1]
    reach = (n_steps + hop) // 2
    for w, start in enumerate(np.asarray(starts).tolist()):
        to = last_to if last_to is not None and w == len(starts) - 1 else start + reach
        if to > owned:
            acc[owned - offset:to - offset] = values[w, owned - start:to - start]
            owned = to
    return owned


class EventTracker:
    """Runs of final per-sample scores above the threshold -> events (runs closer than
    ``merge_gap`` samples are one event)."""

    def __init__(self, threshold: float, merge_gap: int, channels: tuple[str, ...],
                 groups: tuple[str, ...]) -> None:
        self.threshold, self.merge_gap = threshold, merge_gap
        self.channels, self.groups = channels, groups
        self.open: dict[str, Any] | None = None  # the event being built
        self.quiet = 0  # samples below the threshold since the open event's last exceedance

    def feed(self, point: NDArray[Any], channel: NDArray[Any], time: NDArray[Any],
             position: NDArray[Any] | None, period: float) -> list[Event]:
        """Consume final per-sample scores (in order); return the events that ended."""
        done: list[Event] = []
        prev: int = -1  # last hit in this block
        for i in np.flatnonzero(point > self.threshold):
            quiet_before = i - prev - 1 if prev >= 0 else self.quiet + i
            if self.open is not None and quiet_before >= self.merge_gap:
                done.append(self._close())
            if self.open is None:
                self.open = {"start": time[i], "score": -np.inf}
            ev = self.open
            ev["end"] = time[i] + period
            if point[i] > ev["score"]:
                ev.update(score=float(point[i]), peak=float(time[i]),
                          channel=int(np.argmax(channel[i])),
                          position=None if position is None else float(position[i]))
            prev = int(i)
        if self.open is not None:
            self.quiet = len(point) - 1 - prev if prev >= 0 else self.quiet + len(point)
            if self.quiet >= self.merge_gap:
                done.append(self._close())
        return done

    def close(self) -> list[Event]:
        return [self._close()] if self.open is not None else []

    def _close(self) -> Event:
        ev, self.open, self.quiet = self.open, None, 0
        assert ev is not None
        c = ev["channel"]
        return Event(start_s=float(ev["start"]), end_s=float(ev["end"]), peak_s=ev["peak"],
                     channel=self.channels[c], group=self.groups[c], score=ev["score"],
                     threshold=self.threshold, position_m=ev["position"])


def uses_floor(detector: Detector, preparation: Preparation, fs: float) -> bool:
    """Whether ``detector`` is handed the noise floor of recordings at ``fs``: it uses one (a
    fitted detector: it was fitted with one), and the preparation resamples (at a recording's
    own rate no band is dropped to measure it)."""
    uses = detector.fitted_uses() if hasattr(detector, "stats_") else detector.uses
    return NOISE_FLOOR in uses and preparation.ratio(fs) != (1, 1)


class StreamingDetector:
    """Score a recording block by block; see the module docstring.

    ``on_samples(time, point, channel, position)``, if given, receives every finalised stretch
    of per-sample scores (for a score trace or a plot; position is NaN when unknown).
    ``on_centres(time, channel, position)``, if given, receives the same stretches with each
    sample's per-channel score taken from the one window it is most central in
    (:func:`assign_centres`) instead of the maximum over the windows that cover it: the score
    profile that ``railwatch scan`` keeps for the track map. A window whose last samples enter
    a louder stretch of track judges them by the quieter rest of the window, and the maximum
    keeps that; the window in which they are central does not.
    """

    def __init__(self, detector: Detector, layout: Layout, preparation: Preparation,
                 threshold: float | None = None, merge_gap_s: float = 0.5,
                 on_samples: Callable[[NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any]],
                                      None] | None = None,
                 on_centres: Callable[[NDArray[Any], NDArray[Any], NDArray[Any]],
                                      None] | None = None) -> None:
        n_channels = len(layout.channels)
        if n_channels != detector.n_channels_:
            raise RailwatchError(
                f"the layout names {n_channels} channels but the model was trained on "
                f"{detector.n_channels_}: use the layout the model was trained with")
        self.detector, self.layout, self.prep = detector, layout, preparation
        self.up, self.down = preparation.ratio(layout.fs)
        self.fs = preparation.output_rate(layout.fs)
        self.window = preparation.samples(preparation.window_s, layout.fs, "the window")
        if self.window != detector.n_steps_:
            raise RailwatchError(
                f"windows of {preparation.window_s:g} s at {self.fs:g} Hz are {self.window} "
                f"samples, but the model takes {detector.n_steps_}")
        self.hop = preparation.samples(preparation.detect_hop_s, layout.fs, "the hop")
        if self.hop > self.window:
            raise RailwatchError(f"a hop of {preparation.detect_hop_s:g} s is longer than the "
                                 f"{preparation.window_s:g}-s window: samples would go unscored")
        self.threshold = float(detector.threshold_ if threshold is None else threshold)
        #: Steps at each end of a window whose scores the merge leaves to the overlapping
        #: windows (the detector's ``edge_guard``, at most what the hop leaves covered).
        self.guard = max(0, min(detector.edge_guard,
                                (self.window - self.hop) // 2))
        self.tracker = EventTracker(self.threshold, max(1, round(merge_gap_s * self.fs)),
                                    layout.channels, layout.groups)
        self.on_samples, self.on_centres = on_samples, on_centres
        self.resampler = Resampler(self.up, self.down, n_channels)
        #: The noise floor of the band the resampling drops, for a detector that uses it
        #: (:mod:`railwatch.recordings.floor`): one row per resampled sample, as ``samples``.
        self.meter = NoiseFloor(self.up, self.down, n_channels) \
            if uses_floor(detector, preparation, layout.fs) else None
        self.floor = np.zeros((0, n_channels))
        self.pending_floor = np.zeros((0, n_channels))
        self.n_in = 0  # raw samples received
        self.distance = 0.0  # integrated speed (m) up to raw sample n_in
        self.t0: float | None = None  # time of raw sample 0 (time column), else 0
        self.samples = np.zeros((0, n_channels), np.float32)  # resampled, from buf_start
        self.aux = np.zeros((0, 2))  # time, position of each resampled sample
        self.pending_aux: list[NDArray[Any]] = []  # aux of outputs not yet out of the filter
        self.buf_start = 0  # output index of samples[0]
        self.next_window = 0  # output index of the next window's start
        self.final = 0  # outputs before this index are final
        self.owned = 0  # outputs before this index have their central score (assign_centres)
        self.point = np.zeros(0)  # merged scores of outputs final .. buf end
        self.channel = np.zeros((0, n_channels))
        self.centre = np.zeros((0, n_channels))  # central per-channel scores, final .. buf end
        self.closed = False

    # -- public ------------------------------------------------------------------------------
    def push(self, chunk: Chunk | NDArray[Any]) -> list[Event]:
        """Feed raw samples (a :class:`Chunk`, or an (n, C) array); returns finished events."""
        if self.closed:
            raise RailwatchError("this stream is closed: start a new StreamingDetector")
        if not isinstance(chunk, Chunk):
            chunk = Chunk(self.n_in, np.asarray(chunk, dtype=np.float32))
        data = chunk.data
        if data.ndim != 2 or data.shape[1] != len(self.layout.channels):
            raise RailwatchError(f"expected samples of shape (n, {len(self.layout.channels)}), "
                                 f"got {data.shape}")
        if not np.isfinite(data).all():
            raise RailwatchError(f"non-finite sample in the block starting at sample {self.n_in}")
        self._collect_aux(chunk)
        if self.meter is not None:
            self.pending_floor = np.concatenate([self.pending_floor, self.meter.push(data)])
        return self._advance(self.resampler.push(data), end=False)

    def close(self) -> list[Event]:
        """End of the recording: score the tail and return the last events."""
        if self.closed:
            return []
        self.closed = True  # even if the tail fails: its padding must not be scored twice
        if self.meter is not None:
            self.pending_floor = np.concatenate([self.pending_floor, self.meter.flush()])
        events = self._advance(self.resampler.flush(), end=True)
        return events + self.tracker.close()

    # -- internals ---------------------------------------------------------------------------
    def _collect_aux(self, chunk: Chunk) -> None:
        """Time and position of the outputs whose input time ``k · down / up`` falls in this
        chunk: positions (and a time column) are read at the raw sample at or just before it."""
        n = len(chunk.data)
        up, down = self.up, self.down
        ks = np.arange(-(-self.n_in * up // down), ((self.n_in + n) * up - 1) // down + 1)
        at = ks * down / up  # input time of each output, in samples
        pick = ks * down // up - self.n_in  # the raw sample at or before it, in this chunk
        if chunk.time is not None:
            if self.t0 is None:
                self.t0 = float(chunk.time[0]) - self.n_in / self.layout.fs
            t = chunk.time[pick] + (at % 1) / self.layout.fs
        else:
            t = at / self.layout.fs + (self.t0 or 0.0)
        if chunk.position is not None:
            pos = chunk.position[pick]
        elif chunk.speed is not None:
            travelled = self.distance + np.cumsum(chunk.speed) / self.layout.fs
            pos = np.concatenate([[self.distance], travelled])[:-1][pick]  # at each sample
            self.distance = float(travelled[-1])
        else:
            pos = np.full(len(ks), np.nan)
        self.pending_aux.append(np.stack([t, pos], axis=1))
        self.n_in += n

    def _advance(self, out: NDArray[np.float32], end: bool) -> list[Event]:
        if len(out):
            aux = np.concatenate(self.pending_aux) if self.pending_aux else np.zeros((0, 2))
            self.aux = np.concatenate([self.aux, aux[:len(out)]])
            self.pending_aux = [aux[len(out):]]
            self.samples = np.concatenate([self.samples, out])
            if self.meter is not None:  # the floor runs ahead of the resampler's delay
                self.floor = np.concatenate([self.floor, self.pending_floor[:len(out)]])
                self.pending_floor = self.pending_floor[len(out):]
            self.point = np.concatenate([self.point, np.full(len(out), -np.inf)])
            self.channel = np.concatenate([self.channel,
                                           np.full((len(out), self.channel.shape[1]), -np.inf)])
            self.centre = np.concatenate([self.centre,
                                          np.full((len(out), self.centre.shape[1]), -np.inf)])
        n_out = self.buf_start + len(self.samples)
        starts = list(range(self.next_window, n_out - self.window + 1, self.hop))
        if end:  # as frame(cover_end=True): a last window ending at the last sample
            if n_out < self.window:
                raise RailwatchError(f"the recording is shorter than one window "
                                     f"({n_out} < {self.window} samples at {self.fs:g} Hz)")
            last_regular = starts[-1] if starts else self.next_window - self.hop
            if not starts or last_regular + self.window < n_out:
                # The last window scores the central profile up to the last sample (scored
                # again if it was the previous block's last: then it did not know it was).
                starts.append(n_out - self.window)
        if starts:
            at = np.asarray(starts) - self.buf_start
            windows = gather_windows(self.samples, at, self.window)
            context = None if self.meter is None else \
                {NOISE_FLOOR: gather_windows(self.floor, at, self.window)}
            scores = self.detector.score(windows, context)
            last = n_out if end else None  # the recording's last sample, once it is known
            merge_max(self.point, scores.point, np.asarray(starts), self.final, self.guard, last)
            merge_max(self.channel, scores.channel, np.asarray(starts), self.final, self.guard,
                      last)
            self.owned = assign_centres(self.centre, scores.channel, np.asarray(starts),
                                        self.final, self.owned, self.hop, last)
            self.next_window = starts[-1] + self.hop
        # Final: no later window covers it. Regular windows start at next_window or later; the
        # tail window (added at the end) starts at n_total − window ≥ n_out − window.
        final_to = n_out if end else min(self.next_window, n_out - self.window)
        return self._finalise(final_to)

    def _finalise(self, upto: int) -> list[Event]:
        k = upto - self.final
        if k <= 0:
            return []
        point, channel = self.point[:k], self.channel[:k]
        aux = self.aux[self.final - self.buf_start:upto - self.buf_start]
        position = None if np.isnan(aux[:, 1]).all() else aux[:, 1]
        if self.on_samples is not None:
            self.on_samples(aux[:, 0], point, channel, aux[:, 1])
        if self.on_centres is not None:
            self.on_centres(aux[:, 0], self.centre[:k], aux[:, 1])
        first, stop = self.resampler.clean(self.n_in)  # stop is known once closed
        at = np.arange(self.final, upto)
        edge = (at < first) | ((at >= stop) if self.closed else False)
        if edge.any():  # the resampling filter read past the recording: no events there
            point, channel = np.where(edge, -np.inf, point), \
                np.where(edge[:, None], -np.inf, channel)
        events = self.tracker.feed(point, channel, aux[:, 0], position, 1.0 / self.fs)
        self.point, self.channel, self.centre = self.point[k:], self.channel[k:], self.centre[k:]
        self.final = upto
        # Needed by later windows, and by the last window again if the recording ends there.
        keep = max(0, min(self.final, self.next_window - self.hop) - self.buf_start)
        self.samples, self.aux = self.samples[keep:], self.aux[keep:]
        if self.meter is not None:
            self.floor = self.floor[keep:]
        self.buf_start += keep
        return events
