"""Where a simulated line lies on the earth, and the GNSS fixes a pass records there.

**The line** starts at :data:`ORIGIN` (an arbitrary point in open country; no real line is
meant) and runs, from the track's seed, as straights and circular curves in turn: straights
of 300-1,500 m, curves of 300-1,000 m with radii of 1,500-5,000 m either way, the plan of a
main line for 120-200 km/h (railwatch's design choice: a line's plan only shapes the map a
user sees, nothing in the signals). Chainage ``s`` (the track position, m) is the distance
along it.

**A fix** is where the receiver says the antenna was: the true point plus an error per axis
(east, north) that wanders as a first-order Gauss-Markov process (standard deviation
:data:`FIX_SIGMA_M`, correlation time :data:`FIX_TAU_S`), new :data:`FIX_HZ` times a second
and held between (a logger writes the last fix on every sample). A stand-alone receiver's
error is correlated over tens of seconds (multipath, the atmosphere; Groves, *Principles of
GNSS, Inertial, and Multisensor Integrated Navigation Systems*, 2nd ed., 2013, ch. 9); the
GPS Standard Positioning Service promises a horizontal error under 8 m 95 % of the time
(GPS SPS Performance Standard, 5th ed., 2020, table 3.8-1): σ = 2 m per axis (95 % of
horizontal errors under 4.9 m) is within it.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

FloatArray = NDArray[np.float64]

#: Where chainage 0 lies (latitude, longitude; degrees, WGS 84) and the line's first heading
#: (degrees clockwise from north).
ORIGIN = (51.0, 10.0)
HEADING_DEG = 60.0
#: The fixes' error per axis (m), its correlation time (s) and how often a fix comes (Hz).
FIX_SIGMA_M = 2.0
FIX_TAU_S = 60.0
FIX_HZ = 10.0
#: Mean earth radius (m; IUGG): metres east and north to degrees near :data:`ORIGIN`.
EARTH_RADIUS_M = 6_371_008.8
#: The line's points are this far apart (m).
STEP_M = 5.0


def line(start_m: float, end_m: float, seed: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The line from chainage ``start_m`` to ``end_m`` (it must hold 0): chainage, east and
    north (m from :data:`ORIGIN`) every :data:`STEP_M`. Its curves are drawn from
    ``start_m`` on: one track's passes all take the same extent (``simulate``: the track's)."""
    rng = np.random.default_rng([seed, 401])
    s = np.arange(math.floor(start_m / STEP_M), math.ceil(end_m / STEP_M) + 1) * STEP_M
    curvature = np.zeros(len(s))
    at, straight = float(s[0]), True
    while at < s[-1]:  # straights and curves in turn, from the line's first point
        length = rng.uniform(300, 1500) if straight else rng.uniform(300, 1000)
        if not straight:
            curvature[(s >= at) & (s < at + length)] = rng.choice([-1, 1]) / rng.uniform(
                1500, 5000)
        at, straight = at + length, not straight
    heading = np.cumsum(curvature) * STEP_M
    heading += math.radians(HEADING_DEG) - np.interp(0.0, s, heading)
    east = np.cumsum(np.sin(heading)) * STEP_M
    north = np.cumsum(np.cos(heading)) * STEP_M
    return (np.asarray(s, dtype=float), east - np.interp(0.0, s, east),
            north - np.interp(0.0, s, north))


def to_degrees(east: FloatArray, north: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Metres east and north of :data:`ORIGIN` as latitude and longitude (degrees; a sphere's
    local plane: under a millimetre off over a few km)."""
    lat0, lon0 = ORIGIN
    lat = lat0 + np.degrees(north / EARTH_RADIUS_M)
    lon = lon0 + np.degrees(east / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
    return lat, lon


def fixes(chainage: FloatArray, time: FloatArray, where: tuple[FloatArray, FloatArray,
                                                                FloatArray],
          seed: int) -> tuple[FloatArray, FloatArray]:
    """The latitude and longitude a receiver records at each sample of a pass that truly
    was at ``chainage`` at ``time`` (s) on the line ``where`` (:func:`line`); the error drawn
    from ``seed`` (module docstring)."""
    s, east, north = where
    t = np.asarray(time, dtype=float)
    k = np.floor((t - t[0]) * FIX_HZ).astype(int)  # the fix each sample holds
    n = int(k[-1]) + 1
    rng = np.random.default_rng([seed, 402])
    a = math.exp(-1.0 / (FIX_HZ * FIX_TAU_S))
    kick = rng.normal(0.0, FIX_SIGMA_M * math.sqrt(1 - a * a), (n, 2))
    kick[0] = rng.normal(0.0, FIX_SIGMA_M, 2)  # the first fix's error: the stationary spread
    err = lfilter([1.0], [1.0, -a], kick, axis=0)
    first = np.searchsorted(k, np.arange(n))  # the sample each fix is taken at
    at = np.asarray(chainage, dtype=float)[np.minimum(first, len(t) - 1)]
    e = np.interp(at, s, east) + err[:, 0]
    nn = np.interp(at, s, north) + err[:, 1]
    lat, lon = to_degrees(e, nn)
    return lat[k], lon[k]
