"""Scan many recordings with one model: each recording's events and one combined table, in this
process or as Ray tasks, resumable (a recording scanned by the same model is not scanned again).

For every recording ``NAME.EXT`` the scan folder gets ``NAME.events.csv`` (the events of
``railwatch detect``), ``NAME.profile.npz`` (every per-sample score with its position: what the
track map fuses across passes) and then ``NAME.scan.json`` (the recording, the model, the
stretch of track it covered, when it was scanned and when it was recorded: ``started``, from
the layout's ``timestamp`` column or a ``--dates`` table): written last, it marks the recording
done. Where the layout names ``latitude`` and ``longitude`` columns, the profile also keeps the
recording's route (its GNSS fixes at 10 Hz): what puts the map's places on the earth. A model
that knows its axle boxes' response (``train`` identifies it at field scale) also keeps each
recording's weld test along the track (:mod:`railwatch.detection.welds`): what the map's weld
layer fuses. A recording at field rate keeps each sample's low band too (|acceleration| below
200 Hz, :func:`railwatch.trackmap.trends.low_band`): what a place's trend measures. A scan made
before railwatch kept it is mapped as before, its trends on the detector's score; scan into a
new folder to measure them on the low band.
``events.csv`` combines them all with a ``recording`` column. Only the driver writes; a
Ray task reads its recording and returns its events and profile.
"""

from __future__ import annotations

import csv
import datetime
import io
import json
import os
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.atomic import atomic_path, atomic_savez, sha256_file
from railwatch.detection import pipeline, welds
from railwatch.detectors import model_folder
from railwatch.errors import RailwatchError
from railwatch.recordings.layout import Layout
from railwatch.recordings.prepare import AXLE_GROUPS
from railwatch.recordings.readers import Recording, iso_time, recording_route, recording_start
from railwatch.trackmap import trends
from railwatch.trackmap.folder import (
    COMBINED,
    EVENTS_SUFFIX,
    PROFILE_KIND,
    PROFILE_SUFFIX,
    SCAN_SUFFIX,
    profile_arrays,
    scan_record,
)

#: Ray's memory resource asked per recording task: what one streaming scan needs with room.
TASK_MEMORY = 2 * 1024**3


@dataclass(frozen=True)
class ScanSummary:
    scanned: int  # recordings scanned now
    reused: int  # found finished in the folder
    events: int  # in the combined table
    recording_s: float  # seconds of recording in the folder's table
    wall_s: float


def model_id(model: str | os.PathLike[str]) -> str:
    """What identifies a model across runs: the SHA-256 of its header (which holds the checksums
    of its other files) or of its ONNX file."""
    path = Path(model)
    return sha256_file(path if path.is_file() else path / model_folder.HEADER)[:16]


def _signature(path: Path) -> dict[str, int]:
    stat = path.stat()
    return {"bytes": stat.st_size, "mtime_ns": stat.st_mtime_ns}


def scan(model: str | os.PathLike[str], recordings: Sequence[str | os.PathLike[str]],
         out: str | os.PathLike[str], layout: Layout | None = None,
         threshold: float | None = None, executor: str = "local", address: str | None = None,
         on_recording: Callable[[str, int | None], None] | None = None,
         dates: dict[str, str] | None = None) -> ScanSummary:
    """Scan every recording into ``out`` (module docstring); returns what was done.

    Everything is checked before any scan: the model, every recording's format and columns
    against the layout (the model's unless ``layout`` is given), names that would collide.
    ``on_recording(name, n_events)`` is called as each finishes (``None``: found finished).
    ``dates`` (recording name -> ISO 8601, :func:`read_dates`) dates recordings, before the
    layout's ``timestamp`` column; a recording scanned before takes a new date without a scan.
    """
    began = time.perf_counter()
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise RailwatchError(f"--out {out} is a file: give a folder for the scan")
    rm = pipeline.load_recording_model(model)
    layout = rm.layout_for(layout)
    paths = [Path(p) for p in recordings]
    if not paths:
        raise RailwatchError("no recordings to scan: give files, folders or globs")
    names = [p.stem for p in paths]
    twins = sorted({n for n in names if names.count(n) > 1})
    if twins:
        raise RailwatchError(f"two recordings are named {twins[0]} (in different folders): "
                             "their events would share a file; rename one")
    if len(layout.channels) != rm.detector.n_channels_:
        raise RailwatchError(f"the layout names {len(layout.channels)} channels, the model was "
                             f"trained on {rm.detector.n_channels_}")
    for p in paths:  # every file's format and columns, before any work
        Recording(p, layout)
    dates = dates or {}
    started = {p.stem: dates.get(p.stem) or recording_start(p, layout) for p in paths}
    out.mkdir(parents=True, exist_ok=True)
    ident = model_id(model)
    gnss = bool(layout.latitude and layout.longitude)
    todo = [p for p in paths if not _done(out, p, ident, threshold, gnss)]
    for p in paths:
        if p not in todo:
            _redate(out / f"{p.stem}{SCAN_SUFFIX}", started[p.stem])
            if on_recording is not None:
                on_recording(p.stem, None)
    args = (str(model), layout.to_dict(), threshold)
    results: Iterator[tuple[Path, Any]]
    if executor == "local":
        results = ((p, _scan_one(p, *args, detector=rm)) for p in todo)
    elif executor == "ray":
        from railwatch.parallel import ray_imap

        results = ray_imap(_scan_one, todo, args, address=address, memory_bytes=TASK_MEMORY)
    else:
        raise RailwatchError(f"unknown executor {executor!r}: use local or ray")
    for path, (events_text, profile, info) in results:
        name = path.stem
        with atomic_path(out / f"{name}{EVENTS_SUFFIX}") as tmp:
            tmp.write_text(events_text)
        atomic_savez(out / f"{name}{PROFILE_SUFFIX}", profile)
        info = scan_record(**info, model=ident, model_path=str(model),
                           signature=_signature(path), threshold_given=threshold,
                           scanned=datetime.datetime.now().isoformat(timespec="seconds"),
                           started=started[name])
        with atomic_path(out / f"{name}{SCAN_SUFFIX}") as tmp:  # last: marks it done
            tmp.write_text(json.dumps(info, indent=1))
        if on_recording is not None:
            on_recording(name, int(info["events"]))
    n_events, seconds = _combine(out, [p.stem for p in paths])
    return ScanSummary(scanned=len(todo), reused=len(paths) - len(todo), events=n_events,
                       recording_s=seconds, wall_s=time.perf_counter() - began)


def _redate(info_path: Path, started: str | None) -> None:
    """A finished recording's date, changed in place when it is given anew."""
    info = json.loads(info_path.read_text())
    if started is not None and info.get("started") != started:
        info["started"] = started
        with atomic_path(info_path) as tmp:
            tmp.write_text(json.dumps(scan_record(**info), indent=1))


def read_dates(path: str | os.PathLike[str]) -> dict[str, str]:
    """A dates table (``scan --dates``): columns ``recording`` (a file's name, with or without
    its folder and extension) and ``started`` (ISO 8601, or seconds since 1970-01-01 UTC);
    recording name -> ISO 8601."""
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            if not {"recording", "started"} <= set(reader.fieldnames or []):
                raise RailwatchError(f"--dates {path}: a dates table has the columns recording "
                                     "and started (ISO 8601, e.g. 2026-03-01T08:15:00Z)")
            rows = list(reader)
    except OSError as e:
        raise RailwatchError(f"--dates {path}: cannot read it ({e.strerror or e})") from None
    out = {}
    for n, row in enumerate(rows, start=2):
        text = (row["started"] or "").strip()
        try:
            value: Any = float(text)
        except ValueError:
            value = text
        out[Path((row["recording"] or "").strip()).stem] = iso_time(
            value, f"--dates {path}, line {n}")
    return out


def _done(out: Path, path: Path, ident: str, threshold: float | None, gnss: bool) -> bool:
    """Scanned before by this model, with this threshold, from this very file (and with its
    GNSS route when the layout names one)."""
    info_path = out / f"{path.stem}{SCAN_SUFFIX}"
    if not info_path.is_file() or not all((out / f"{path.stem}{suffix}").is_file()
                                          for suffix in (EVENTS_SUFFIX, PROFILE_SUFFIX)):
        return False
    try:
        info = json.loads(info_path.read_text())
        return bool(info.get("model") == ident and info.get("threshold_given") == threshold
                    and info.get("signature") == _signature(path)
                    and info.get("profile") == PROFILE_KIND
                    and bool(info.get("gnss", False)) == gnss)
    except (OSError, ValueError):
        return False


def _scan_one(path: Path, model: str, layout: dict[str, Any], threshold: float | None,
              detector: pipeline.RecordingModel | None = None
              ) -> tuple[str, dict[str, Any], dict[str, Any]]:
    """Detect on one recording: (its events as CSV text, its score profile, what the scan
    records of it)."""
    rm = detector or pipeline.load_recording_model(model)
    lay = Layout.from_dict(layout, "the scan's layout")
    rec = Recording(path, lay)
    began = time.perf_counter()
    profile = pipeline.Profile()
    result = pipeline.detect(rm.detector, rec, rm.preparation,
                             rm.threshold if threshold is None else threshold, profile=profile)
    position = np.asarray(result.trace.position, dtype=float)
    finite = position[np.isfinite(position)]
    info = scan_record(
        recording=str(path), duration_s=rec.duration_s, events=len(result.events),
        threshold=result.threshold, detect_s=time.perf_counter() - began,
        position_first_m=float(finite[0]) if len(finite) else None,
        position_last_m=float(finite[-1]) if len(finite) else None,
        profile=PROFILE_KIND, wheel_turns_m=result.wheel_turns,
        scale=rm.layout.scale,  # the model's: track-map's --min-events follows it
        gnss=bool(lay.latitude and lay.longitude),
    )
    weld = None
    if rm.response is not None:  # the weld test (recordings.rails): its own arrays
        weld = welds.weld_evidence(*welds.axle_motion(rec), rm.response)
    time_s, position_m, score = profile.columns()
    arrays = profile_arrays(time_s, position_m, score, lay.channels, lay.groups,
                            route=recording_route(path, lay), weld=weld,
                            band=band_at(rec, time_s))
    return pipeline.events_text(result.events, "csv"), arrays, info


def band_at(rec: Recording, time_s: NDArray[np.float64]) -> NDArray[np.float32] | None:
    """The recording's low band (``trends.low_band``) at the profile's sample times ``time_s``
    ((n,): the highest over the axle-box group's channels, every channel's where no group is
    one; its own samples where they are one to one, as at field scale); None where the rate
    keeps none."""
    lay = rec.layout
    if lay.fs < trends.BAND_RATE * trends.BAND_HZ:
        return None
    axle = [(c, g) for c, g in zip(lay.channels, lay.groups, strict=True)
            if g.lower() in AXLE_GROUPS]
    if axle:
        lay = replace(lay, channels=tuple(c for c, _ in axle), groups=tuple(g for _, g in axle))
    chunk = Recording(rec.path, lay).read()
    band = trends.low_band(chunk.data, lay.fs)
    if band is None:
        return None
    top = np.fmax.reduce(band, axis=1)  # NaN only where every channel is
    if len(top) == len(time_s):
        return top.astype(np.float32)
    at = chunk.time if chunk.time is not None else np.arange(len(top)) / lay.fs
    return np.interp(time_s, at, top).astype(np.float32)


def _combine(out: Path, names: list[str]) -> tuple[int, float]:
    """``events.csv``: every scanned recording's events, a ``recording`` column first."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["recording", *pipeline.EVENT_FIELDS])
    count, seconds = 0, 0.0
    for name in sorted(set(names)):
        info = json.loads((out / f"{name}{SCAN_SUFFIX}").read_text())
        seconds += float(info["duration_s"])
        with open(out / f"{name}{EVENTS_SUFFIX}", newline="") as fh:
            for row in csv.DictReader(fh):
                writer.writerow([name, *(row[k] for k in pipeline.EVENT_FIELDS)])
                count += 1
    with atomic_path(out / COMBINED) as tmp:
        tmp.write_text(buf.getvalue())
    return count, seconds
