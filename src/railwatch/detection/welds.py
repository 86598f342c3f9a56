"""The weld test along a recording: the rails' height from the axle boxes (:mod:`railwatch.
recordings.rails`) tested for welds (:mod:`railwatch.scoring.dips`).

``train`` identifies the axle boxes' response from its recordings (:func:`identify_response`);
``scan`` measures every recording's rails and keeps the test's ``z`` along the track
(:func:`weld_evidence`), which the map fuses over passes (:mod:`railwatch.trackmap.welds`). The
test: the heights on a 1-cm grid of distance travelled, whitened by the pass's own spectra
(robust: the mean over 80-m segments less the quarter that stand out most, so that the few
holding a defect or a turnout do not raise the whole track's) and matched to a bank of weld
shapes, both rails together; wavelengths from the shortest the pass measured everywhere to
:data:`LONGEST_M`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from railwatch.errors import RailwatchError
from railwatch.recordings import rails
from railwatch.recordings.layout import Layout
from railwatch.recordings.prepare import AXLE_GROUPS
from railwatch.recordings.readers import Recording
from railwatch.scoring.dips import DX_M, rail_spectra, weld_bank, whitened_scan

FloatArray = NDArray[np.float64]

#: The longest wavelength weighed (m; a weld's dip is 0.6-1.2 m) and the segments of the
#: spectra's estimate (m). The ends: each extended by its mirror image over MIRROR_M, and the
#: test left out within EDGE_M of them (on a development pass the test near an end differs from
#: the whole pass's by up to 0.9 within 5 m of it, 0.3 at 10-15 m, 0.15 at 30 m; without the
#: mirror 3.7, 0.9, 0.3).
LONGEST_M = 5.0
SEGMENT_M = 81.92
MIRROR_M = 50.0
EDGE_M = 10.0
#: The resolution kept of the weld test along a recording (m): its highest ``z`` per step.
KEEP_M = 0.05


def axle_pair(layout: Layout) -> tuple[str, str] | None:
    """The two channels of the layout's axle-box group (:data:`~railwatch.recordings.prepare.
    AXLE_GROUPS`), in the layout's order: the left and the right axle box of one wheelset;
    None without exactly two."""
    names = [c for c, g in zip(layout.channels, layout.groups, strict=True)
             if g.lower() in AXLE_GROUPS]
    return (names[0], names[1]) if len(names) == 2 else None


def axle_motion(recording: Recording) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                               NDArray[np.float64], NDArray[np.float64]]:
    """A recording's two axle boxes (:func:`axle_pair`), speed (m/s) and position (m): the
    layout's columns, or the speed from the position's steps (over 0.1 s), or the position
    from the integrated speed."""
    layout = recording.layout
    pair = axle_pair(layout)
    if pair is None or not (layout.speed or layout.position):
        raise RailwatchError("the weld test needs the two axle boxes of one wheelset (a group "
                             "named axle of two channels) and a speed or position column")
    lean = replace(layout, channels=pair, groups=("axle", "axle"))
    chunk = Recording(recording.path, lean).read()
    left, right = (chunk.data[:, i].astype(np.float64) for i in range(2))
    fs = layout.fs
    if chunk.speed is not None:
        speed = np.abs(chunk.speed)
        position = chunk.position if chunk.position is not None else \
            np.concatenate([[0.0], np.cumsum(speed[:-1]) / fs])
    else:
        assert chunk.position is not None
        position = chunk.position
        lag = max(1, int(round(0.1 * fs)))
        step = np.abs(position[lag:] - position[:-lag]) * fs / lag
        speed = np.interp(np.arange(len(position)), np.arange(len(step)) + lag / 2, step)
    return left, right, speed, position


def identify_response(sources: Sequence[Recording]) -> rails.AxleResponse:
    """The axle boxes' response (:func:`railwatch.recordings.rails.identify`) from recordings
    of one vehicle."""
    pairs = [axle_motion(r)[:3] for r in sources]
    return rails.identify(pairs, sources[0].layout.fs)


def weld_z(heights: FloatArray, dx: float = DX_M, shortest_m: float = 0.02) -> FloatArray:
    """(2, n): the weld test's ``z`` along heights (2, n) on a grid of ``dx`` (module
    docstring), wavelengths ``shortest_m`` to :data:`LONGEST_M` weighed. The heights are
    extended by their mirror image at both ends (:data:`MIRROR_M`) so that the whitening meets
    no step there; ``z`` is NaN within :data:`EDGE_M` of either end, and everywhere on a stretch
    too short to measure its spectra."""
    n = heights.shape[1]
    edge = int(round(EDGE_M / dx))
    segment = int(round(SEGMENT_M / dx))
    out = np.full((2, n), np.nan)
    if n < 2 * edge + segment:
        return out
    spectra = rail_spectra([heights], dx, segment=segment, robust=True)
    pad = min(int(round(MIRROR_M / dx)), n - 2)
    mirrored = np.concatenate([heights[:, pad:0:-1], heights, heights[:, -2:-pad - 2:-1]],
                              axis=1)
    z = whitened_scan(mirrored, spectra, weld_bank(dx), dx,
                      band_m=(shortest_m, LONGEST_M))[:, pad:pad + n]
    out[:, edge:n - edge] = z[:, edge:n - edge]
    return out


def weld_evidence(left: FloatArray, right: FloatArray, speed: FloatArray,
                  position: FloatArray, response: rails.AxleResponse
                  ) -> tuple[FloatArray, FloatArray]:
    """A recording's weld test along the track: every :data:`KEEP_M` of distance travelled,
    its recorded position (m) and the highest ``z`` of the left and of the right wheel's rail
    there ((k,), (k, 2)); NaN where the test is not valid. ``position`` is each sample's
    recorded position (m), in either direction along the track."""
    if response.fs <= 0 or len(left) < 2:
        raise RailwatchError("the weld test needs a recording of two samples at least")
    heights = rails.rail_heights(left, right, response)
    travelled = np.maximum.accumulate(np.abs(position - position[0]))
    start, grid = rails.on_distance(heights, travelled, DX_M)
    z = weld_z(grid, shortest_m=rails.shortest_wavelength(response.fs, speed))
    step = int(round(KEEP_M / DX_M))
    n = z.shape[1] // step * step
    blocks = z[:, :n].reshape(2, -1, step)
    with np.errstate(invalid="ignore"):
        best = np.where(np.isnan(blocks).all(axis=2), np.nan,
                        np.nanmax(np.where(np.isnan(blocks), -np.inf, blocks), axis=2))
    centre = start + (np.arange(best.shape[1]) * step + (step - 1) / 2) * DX_M
    recorded = np.interp(centre, travelled, position)
    return recorded, best.T.astype(np.float32)
