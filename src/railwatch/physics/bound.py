"""What the track allows: a defect's detectability from the rails' own geometry.

The oracle of the physics bench knows each pass's clean twin, so it knows the track's
irregularity *as drawn* and finds every defect; no detector can know that. This bound knows
less, and what a detector could know: the track's **statistics** (the two rails' spectra and
their cross-spectrum, estimated on clean tracks) and the defect's **shape**, and it sees the
rails' height itself: no vehicle, no sensor noise, no speed. A vehicle is a linear filter of
that height plus noise, and repeated passes see the same height, so no detector whose
knowledge of the track is its statistics can do better from any number of passes (for a
Gaussian track, which the simulator's irregularity and roughness are; the static deflection's
soft and voided sleepers are in the spectra too).

The test is the whitened matched filter of a bank of the simulator's weld shapes
(:mod:`railwatch.scoring.dips`, whose ``z`` is N(0, 1) where there is no defect and the defect's
detectability ``d'`` at one), run on the true height of both rails; wavelengths outside
:data:`BAND_M` get no weight (a vehicle's accelerometers do not measure a rail's 100-m waves,
and the profile grid's shortest waves are the contact patch's). A threshold is set on clean
tracks, for a number of false places per km; a defect is found when the largest ``z`` near it
clears it.

Used by ``benchmarks/physics.py`` ("What the track allows"); the derivation and its checks:
``docs/physics.md``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.signal import find_peaks

from railwatch.errors import RailwatchError
from railwatch.physics.features import Item
from railwatch.scoring.dips import (  # noqa: F401 - the bound's test, named here for its users
    BAND_M,
    DX_M,
    RailSpectra,
    rail_spectra,
    whitened_scan,
)

FloatArray = NDArray[np.float64]

#: The profile grid of the bound (m): the weld's shortest part, its crown, is 5-15 cm.
BOUND_DX_M = DX_M
#: Welds of the bank: every length and crown share the simulator draws from (``features``).
WELD_LENGTHS_M = (0.6, 0.8, 1.0, 1.2)
WELD_CROWNS = (0.0, 0.25, 0.5)  # of the dip's depth
WELD_CROWN_M = 0.1


def weld_templates(dx: float = BOUND_DX_M) -> list[FloatArray]:
    """The bank of weld shapes: ``features``' weld 1 mm deep (heights in m), for every length
    of :data:`WELD_LENGTHS_M` and crown share of :data:`WELD_CROWNS`."""
    out = []
    for length in WELD_LENGTHS_M:
        for crown in WELD_CROWNS:
            it = Item(0, "weld", 0.0, length, 1.0, 1, (("crown_mm", crown),
                                                        ("crown_m", WELD_CROWN_M)))
            out.append(it.height(np.arange(0.0, length + dx / 2, dx)))
    return out


def peaks(zmap: FloatArray, dx: float = BOUND_DX_M, apart_m: float = 5.0) -> FloatArray:
    """The places of a (2, n) ``z`` map: its largest values over both rails at least
    ``apart_m`` apart (descending)."""
    top = zmap.max(axis=0)
    at, _ = find_peaks(top, distance=max(1, int(round(apart_m / dx))))
    return np.sort(top[at])[::-1]


def level(place_values: Sequence[float], km: float, per_km: float) -> float:
    """The threshold that ``per_km`` false places per km allow, from the places of clean tracks
    of ``km`` km in all (the value of the ``per_km · km``-th largest)."""
    k = int(np.floor(per_km * km))
    values = np.sort(np.asarray(place_values, dtype=float))[::-1]
    if k < 1 or k > len(values):
        raise RailwatchError(f"{km:g} km of clean track cannot set a level of {per_km:g} false "
                             f"places per km: simulate at least {1 / per_km:g} km")
    return float(values[k - 1])


def track_geometry(path: FloatArray, dx_from: float, dx: float = BOUND_DX_M) -> FloatArray:
    """A track's (2, n) rail heights on the bound's grid: means of ``dx / dx_from`` samples."""
    step = int(round(dx / dx_from))
    if step < 1 or abs(step * dx_from - dx) > 1e-9:
        raise RailwatchError(f"the bound's grid ({dx:g} m) must be a multiple of the track's "
                             f"({dx_from:g} m)")
    n = path.shape[1] // step * step
    return np.asarray(path[:, :n].reshape(2, -1, step).mean(axis=2))
