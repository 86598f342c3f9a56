"""Recordings end to end: training windows from a vehicle's runs, detection along a recording,
events to CSV/JSON and a plot. The command line (``railwatch train --recordings``, ``railwatch
detect``) is a thin layer over these functions.

A model trained on recordings carries ``recording.json`` beside its weights: the layout it was
trained with and the preparation (rate, window, hops, the wheel comb), so that ``detect`` prepares
new recordings the same way without being told again.
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.atomic import atomic_path
from railwatch.detection import welds
from railwatch.detection.stream import Event, StreamingDetector, uses_floor
from railwatch.detectors import model_folder
from railwatch.detectors.api import Detector
from railwatch.detectors.registry import load_detector
from railwatch.errors import RailwatchError, one_line
from railwatch.recordings import rails, wheel
from railwatch.recordings.floor import NOISE_FLOOR, NoiseFloor
from railwatch.recordings.layout import Layout
from railwatch.recordings.prepare import Preparation, Resampler, frame
from railwatch.recordings.readers import CHUNK_ROWS, Chunk, Recording
from railwatch.scoring.thresholds import GumbelNull, ThresholdRule

EVENT_FIELDS = ("start_s", "end_s", "peak_s", "channel", "group", "score", "threshold",
                "position_m")


# ----------------------------------------------------------------------------- training
def prepared_chunks(recording: Recording, prep: Preparation, rows: int = CHUNK_ROWS,
                    turns: list[float | None] | None = None) -> Iterator[Chunk]:
    """The recording's chunks as the detector is to see them before resampling: as read, or
    with the wheel's turns combed out (``prep.wheel_turns``, :mod:`railwatch.recordings.wheel`;
    ``turns`` found in the recording unless given)."""
    if prep.wheel_turns:
        return wheel.combed(recording, prep.wheel_turns, rows, turns)
    return recording.chunks(rows)


def training_windows(recordings: Sequence[Recording], prep: Preparation,
                     progress: Callable[[int], None] | None = None) -> NDArray[np.float32]:
    """Windows (N, T, C) of every recording: resampled, framed every ``train_hop_s``."""
    return training_set(recordings, prep, progress)[0]


def training_set(recordings: Sequence[Recording], prep: Preparation,
                 progress: Callable[[int], None] | None = None, floor: bool = False
                 ) -> tuple[NDArray[np.float32], dict[str, NDArray[np.float32]]]:
    """:func:`training_windows` and the side arrays a detector takes with them: with ``floor``,
    the windows' noise floor (:mod:`railwatch.recordings.floor`), measured in the same pass."""
    out: list[NDArray[np.float32]] = []
    floors: list[NDArray[np.float32]] = []
    for rec in recordings:
        layout = rec.layout
        fs = prep.output_rate(layout.fs)
        window = prep.samples(prep.window_s, layout.fs, "the window")
        hop = prep.samples(prep.train_hop_s, layout.fs, "the training hop")
        resampler = Resampler(*prep.ratio(layout.fs), len(layout.channels))
        meter = NoiseFloor(*prep.ratio(layout.fs), len(layout.channels)) if floor else None
        parts, floor_parts = [], []
        for chunk in prepared_chunks(rec, prep):
            parts.append(resampler.push(chunk.data))
            if meter is not None:
                floor_parts.append(meter.push(chunk.data))
            if progress:
                progress(len(chunk))
        parts.append(resampler.flush())
        signal = np.concatenate(parts)
        if len(signal) < window:
            raise RailwatchError(f"{rec.path} lasts {len(signal) / fs:.2f} s, shorter than one "
                                 f"{prep.window_s:g}-s window")
        out.append(frame(signal, window, hop, cover_end=False)[0])
        if meter is not None:
            level = np.concatenate([*floor_parts, meter.flush()])
            floors.append(frame(level, window, hop, cover_end=False)[0].astype(np.float32))
    context = {NOISE_FLOOR: np.concatenate(floors)} if floor else {}
    return np.concatenate(out), context


#: Windows of normal recording per minute above the event threshold, by the null of the
#: training windows (:func:`event_threshold`; ``train --events-per-minute``), at either scale.
#: A pass of a few minutes then shows at most one or two false events, so that every pass stays
#: under 0.5 per minute, not only their mean. At field scale, on the development physics
#: tracks, 0.6 left 4 of 40 passes above 0.5 per minute, up to 1.13; 0.1: none, at most 0.27,
#: and the same defects but 1-2 % of the weakest
#: (docs/notes/2026-12-03-false-rate-and-crownless-welds.md). At the benchmark scale, on the
#: development trios of stage-5 runs with loud stretches, nuisance-glr found 95-98 % of the
#: defects at 0.3-0.6 false events per minute with 0.6 and, with 0.1 and no events at the
#: recordings' edges, 92-97 % at 0.0-0.2 (the oracle's bound 95-97 %;
#: docs/notes/2026-12-07-the-edges-and-one-operating-point.md): the benchmark scale's 0.6
#: until 2026-12-07.
EVENTS_PER_MINUTE = 0.1


def event_threshold(prep: Preparation, per_minute: float) -> GumbelNull:
    """The event threshold's rule for windows of ``prep``: the Gumbel null of the training
    windows at a tail of ``per_minute`` windows per minute of recording (the default:
    :data:`EVENTS_PER_MINUTE`), so that short field-scale windows do not raise false events by
    their number (2-s windows at 0.1 per minute: a tail of 0.0033; 0.5-s windows: 0.00083)."""
    if not per_minute > 0:
        raise RailwatchError(f"--events-per-minute must be positive, got {per_minute:g}")
    tail = round(per_minute * prep.window_s / 60.0, 12)
    if tail >= 0.5:
        raise RailwatchError(f"--events-per-minute {per_minute:g} puts half of the "
                             f"{prep.window_s:g}-s windows above the threshold: give at most "
                             f"{30.0 / prep.window_s:.0f} (a false event every few minutes "
                             "is 0.1-1)")
    return GumbelNull(tail=tail)


def median_speed(recordings: Sequence[Recording], every: int = 50) -> float | None:
    """The median speed (m/s) over recordings with a speed or position column (every
    ``every``-th sample; from the position's steps without a speed column), or None."""
    speeds = []
    for rec in recordings:
        if not (rec.layout.speed or rec.layout.position):
            continue
        lean = replace(rec.layout, channels=rec.layout.channels[:1],
                       groups=rec.layout.groups[:1])  # read one channel, not all of them
        for chunk in Recording(rec.path, lean).chunks():
            if chunk.speed is not None:
                speeds.append(np.abs(chunk.speed[::every]))
            elif chunk.position is not None and len(chunk.position) > every:
                step = np.abs(np.diff(chunk.position[::every])) * rec.layout.fs / every
                speeds.append(step)
    if not speeds:
        return None
    speed = float(np.median(np.concatenate(speeds)))
    return speed if speed > 0 else None


def recording_info(layout: Layout, prep: Preparation, rule: ThresholdRule,
                   response: rails.AxleResponse | None = None) -> dict[str, str]:
    """The extra file a recordings model carries (``Detector.save(extra_files=...)``): the
    layout, the preparation, the ``rule`` that set the detector's threshold (the value itself
    is stored once, with the detector's statistics) and, when identified, the axle boxes'
    response (the weld test's, :mod:`railwatch.recordings.rails`)."""
    info: dict[str, Any] = {"layout": layout.to_dict(), "preparation": prep.to_dict(),
                            "threshold_rule": rule.describe()}
    if response is not None:
        info["axle_response"] = response.to_dict()
    return model_folder.recording_file(info)


def fit_recording_model(detector: Detector, X: NDArray[np.float32], layout: Layout,
                        prep: Preparation, out: str | os.PathLike[str],
                        rule: ThresholdRule | None = None,
                        response: rails.AxleResponse | None = None,
                        context: dict[str, NDArray[np.float32]] | None = None) -> float:
    """Fit ``detector`` on recordings' windows ``X`` (:func:`training_windows`), set its
    threshold by ``rule`` (default :func:`event_threshold` at :data:`EVENTS_PER_MINUTE`) and save
    the model folder with ``recording.json`` (and the axle boxes' ``response``, if any);
    ``context``: the windows' side arrays (:func:`training_set`); returns the threshold."""
    rule = rule or event_threshold(prep, EVENTS_PER_MINUTE)
    detector.fit(X, context)
    threshold = detector.set_threshold(rule)
    detector.save(out, extra_files=recording_info(layout, prep, rule, response))
    return threshold


@dataclass
class Trained:
    """What :func:`train_on_recordings` did."""

    threshold: float  # the event threshold it set
    per_minute: float  # at this many windows per minute of the training recordings' null
    windows: tuple[int, ...]  # the training windows' shape (N, T, C)
    minutes: float  # of recording read
    field_settings: dict[str, Any]  # the detector's field-scale settings (not overridden)
    response: rails.AxleResponse | None = None  # the axle boxes' (None: no weld test)


def train_on_recordings(name: str, overrides: dict[str, Any], paths: Sequence[Path],
                        layout: Layout, out: str | os.PathLike[str], *,
                        rate: float | str | None = "auto", window_s: float | None = None,
                        hop_s: float | None = None, groups: tuple[str, ...] | None = None,
                        wheel_comb: bool = False, events_per_minute: float | None = None,
                        say: Callable[[str], None] = lambda _: None,
                        progress: bool = True) -> Trained:
    """``railwatch train --recordings``: the registry detector ``name`` (config ``overrides``;
    at field scale its :meth:`field_scale` settings under them) trained without labels on the
    recordings ``paths`` read with ``layout``, prepared as :func:`railwatch.recordings.prepare.
    choose` picks from the layout's scale, rate and the recordings' median speed (``rate``,
    ``window_s``, ``hop_s``, ``groups`` and ``wheel_comb`` override it), its event threshold set
    at ``events_per_minute`` (default :data:`EVENTS_PER_MINUTE`) and saved with its
    ``recording.json`` to ``out``. ``say`` gets the choices in words; every file and setting is
    checked before any is read."""
    from railwatch.detectors import create
    from railwatch.detectors.registry import class_for
    from railwatch.progress import seconds_of_recording
    from railwatch.recordings.prepare import choose

    detector = create(name, overrides)  # unknown names and settings fail before any reading
    if wheel_comb:
        wheel.check_layout(layout)
    sources = [Recording(p, layout) for p in paths]  # every file checked before any reading
    speed = median_speed(sources) if layout.scale == "field" and not window_s else None
    choice = choose(layout.groups, layout.scale, layout.fs, speed, rate=rate, window_s=window_s,
                    hop_s=hop_s, chosen_groups=groups, wheel_turns=2 if wheel_comb else 0)
    prep = choice.preparation
    prep.check(layout.fs)  # fail now, not at detection, on an impossible rate, window or hop
    per_minute = EVENTS_PER_MINUTE if events_per_minute is None \
        else events_per_minute
    rule = event_threshold(prep, per_minute)  # and on an impossible rate of events
    for reason in choice.reasons:
        say(reason)
    mine: dict[str, Any] = {}
    if layout.scale == "field":
        fitted = class_for(name).field_scale(prep.output_rate(layout.fs))
        mine = {k: v for k, v in fitted.items() if k not in overrides}
        if mine:
            say(f"field scale: {name} with " + ", ".join(
                f"{k}={','.join(map(str, v)) if isinstance(v, tuple) else v}"
                for k, v in mine.items()) + " (--set overrides)")
            detector = create(name, {**mine, **overrides})
    layout = layout.select(choice.groups)
    sources = [Recording(p, layout) for p in paths]
    total = sum(r.duration_s for r in sources)
    with seconds_of_recording(total, "reading", progress) as bar:
        X, context = training_set(sources, prep,
                                  progress=lambda n: bar.update(round(n / layout.fs, 3)),
                                  floor=uses_floor(detector, prep, layout.fs))
    if progress:
        say(f"{len(X):,} windows of {X.shape[1]} samples x {X.shape[2]} channels from "
            f"{len(paths)} recording(s), {total / 60:.1f} min; training {name}")
    response = None
    if layout.scale == "field" and welds.axle_pair(layout) and (layout.speed or layout.position):
        try:
            response = welds.identify_response(sources)
            say(f"the axle boxes' response identified from {len(sources)} recording(s) at "
                f"{response.speed_ms[0]:.0f}-{response.speed_ms[1]:.0f} m/s: P2 at "
                f"{response.p2_hz:.0f} Hz (the weld test: the rails' height, fused by "
                "track-map)")
        except RailwatchError as e:
            say(f"no weld test: {e}")
    threshold = fit_recording_model(detector, X, layout, prep, out, rule, response, context)
    return Trained(threshold, per_minute, tuple(X.shape), total / 60, mine, response)


@dataclass
class RecordingModel:
    """A detector trained on recordings, with how to prepare new ones and its event threshold."""

    detector: Detector
    layout: Layout
    preparation: Preparation
    threshold: float
    response: rails.AxleResponse | None = None  # the axle boxes' (the weld test), if trained

    def layout_for(self, given: Layout | None) -> Layout:
        """The layout to read recordings with: the model's, or ``given`` (other column names)
        cut to the model's sensor groups when it names more channels than the model scores."""
        if given is None:
            return self.layout
        if len(given.channels) != len(self.layout.channels) and \
                set(self.layout.groups) <= set(given.groups):
            return given.select(tuple(dict.fromkeys(self.layout.groups)))
        return given


def load_recording_model(model: str | os.PathLike[str]) -> RecordingModel:
    """A model folder written by ``railwatch train --recordings``, or its ``.onnx`` export
    (the network then runs in onnxruntime)."""
    path = Path(model) / model_folder.RECORDING
    if Path(model).suffix.lower() == ".onnx":
        from railwatch.deploy.onnx import load_onnx, read_metadata

        detector = load_onnx(model)
        info, source = read_metadata(model).get("recording"), f"the metadata of {model}"
    else:
        detector = load_detector(model)
        info, source = model_folder.read_recording(model), str(path)
    if info is None:
        raise RailwatchError(
            f"{model} was trained on windows, not recordings (no {model_folder.RECORDING}): "
            "train it with 'railwatch train --recordings FILE... --layout LAYOUT'")
    try:
        layout = Layout.from_dict(info["layout"], source)
        prep = _preparation(info["preparation"])
        prep.check(layout.fs)
        # Models saved before the threshold was stored once keep their event threshold here.
        threshold = float(info["threshold"]) if "threshold" in info else detector.threshold_
        if len(layout.channels) != detector.n_channels_:
            raise ValueError(f"its layout names {len(layout.channels)} channels, the model was "
                             f"trained on {detector.n_channels_}")
        response = rails.AxleResponse.from_dict(info["axle_response"]) \
            if "axle_response" in info else None
    except (KeyError, TypeError, ValueError, RailwatchError) as e:
        raise RailwatchError(f"{source} is damaged ({one_line(e)}): train the model again") \
            from None
    return RecordingModel(detector, layout, prep, threshold, response)


def _preparation(values: Any) -> Preparation:
    """A :class:`Preparation` from ``recording.json``, every field of the right type."""
    if not isinstance(values, dict):
        raise TypeError("its preparation is not a table")
    known = {f.name for f in fields(Preparation)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise KeyError(f"unknown preparation setting {', '.join(unknown)}")
    for key, value in values.items():
        if (value is None and key == "rate") or (isinstance(value, int | float)
                                                  and not isinstance(value, bool)):
            continue
        raise TypeError(f"preparation {key} is {value!r}, not a number")
    return Preparation(**values)


# ----------------------------------------------------------------------------- detection
@dataclass
class Trace:
    """A bounded-size score trace for plotting: the maximum per bin of ``bin_s`` seconds, and the
    track position at each bin's start (NaN without position or speed)."""

    bin_s: float = 0.1
    time: list[float] = field(default_factory=list)
    score: list[float] = field(default_factory=list)
    position: list[float] = field(default_factory=list)
    _pending: list[NDArray[Any]] = field(default_factory=list)

    def add(self, time: NDArray[Any], point: NDArray[Any], channel: NDArray[Any],
            position: NDArray[Any]) -> None:
        self._pending.append(np.stack([time, point, position], axis=1))
        self._bin(final=False)

    def _bin(self, final: bool) -> None:
        if not self._pending:
            return
        rows = np.concatenate(self._pending)
        self._pending = []
        origin = self.time[0] if self.time else rows[0, 0]
        bins = np.floor((rows[:, 0] - origin) / self.bin_s + 1e-9).astype(np.int64)
        k = len(rows) if final else int(np.searchsorted(bins, bins[-1]))  # last bin may grow
        if k:
            starts = np.flatnonzero(np.r_[True, np.diff(bins[:k]) > 0])
            self.time += rows[starts, 0].tolist()
            self.score += np.maximum.reduceat(rows[:k, 1], starts).tolist()
            self.position += rows[starts, 2].tolist()
        if k < len(rows):
            self._pending = [rows[k:]]

    def finish(self) -> Trace:
        self._bin(final=True)
        return self


class Profile:
    """Every per-sample score of a recording at the model's rate: time, the score of each
    channel (from the window the sample is most central in: ``StreamingDetector``'s
    ``on_centres``) and the track position (NaN without position or speed). What ``railwatch
    scan`` keeps for the track map's fusion of passes (a 10-minute recording of six channels at
    100 Hz: 60,000 samples, under 3 MB)."""

    def __init__(self) -> None:
        self._aux: list[NDArray[Any]] = []
        self._channel: list[NDArray[Any]] = []

    def add(self, time: NDArray[Any], channel: NDArray[Any], position: NDArray[Any]) -> None:
        self._aux.append(np.stack([time, position], axis=1))
        self._channel.append(np.asarray(channel, dtype=np.float32))

    def columns(self) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any]]:
        """(time (n,), position (n,), channel scores (n, C)) so far."""
        aux = np.concatenate(self._aux) if self._aux else np.zeros((0, 2))
        channel = np.concatenate(self._channel) if self._channel else np.zeros((0, 0))
        return aux[:, 0], aux[:, 1], channel


@dataclass
class Detection:
    events: list[Event]
    trace: Trace
    threshold: float
    duration_s: float
    has_position: bool
    wheel_turns: dict[str, float] = field(default_factory=dict)  # combed channel: turn, m


def detect(model: Detector, recording: Recording, prep: Preparation,
           threshold: float | None = None, merge_gap_s: float = 0.5,
           chunk_rows: int = CHUNK_ROWS,
           progress: Callable[[int], None] | None = None,
           profile: Profile | None = None) -> Detection:
    """Stream ``recording`` through ``model`` block by block; events and a score trace (and,
    when given, every sample's per-channel score from its most central window into
    ``profile``)."""
    trace = Trace()

    stream = StreamingDetector(model, recording.layout, prep, threshold, merge_gap_s,
                               on_samples=trace.add,
                               on_centres=None if profile is None else profile.add)
    events: list[Event] = []
    turns = wheel.recording_turns(recording, chunk_rows) if prep.wheel_turns else None
    for chunk in prepared_chunks(recording, prep, chunk_rows, turns):
        events += stream.push(chunk)
        if progress:
            progress(len(chunk))
    events += stream.close()
    layout = recording.layout
    return Detection(events, trace.finish(), stream.threshold, recording.duration_s,
                     bool(layout.position or layout.speed),
                     {c: t for c, t in zip(layout.channels, turns or [], strict=False)
                      if t is not None})


# ----------------------------------------------------------------------------- outputs
def events_text(events: Iterable[Event], fmt: str) -> str:
    """Events as CSV (one row each, the columns of :data:`EVENT_FIELDS`) or a JSON list."""
    rows = [e.to_dict() for e in events]
    if fmt == "json":
        return json.dumps(rows, indent=1) + "\n"
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=EVENT_FIELDS, lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: ("" if r[k] is None else
                             f"{r[k]:.4f}" if isinstance(r[k], float) else r[k])
                         for k in EVENT_FIELDS})
    return buf.getvalue()


def write_events(path: str | os.PathLike[str], events: list[Event]) -> Path:
    path = Path(path)
    fmt = {".csv": "csv", ".json": "json"}.get(path.suffix.lower())
    if fmt is None:
        raise RailwatchError(f"--out {path.name}: write events to a .csv or .json file")
    with atomic_path(path) as tmp:
        tmp.write_text(events_text(events, fmt))
    return path


def read_events(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Events back from a CSV or JSON file (numbers as floats)."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        return list(json.loads(path.read_text()))
    with open(path, newline="") as fh:
        return [{k: (float(v) if k not in ("channel", "group") and v != "" else
                     (None if v == "" else v)) for k, v in row.items()}
                for row in csv.DictReader(fh)]
