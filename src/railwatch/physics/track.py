"""The track under the wheel: a rail on discrete supports, in the frequency domain.

The rail is a Timoshenko beam (UIC60) on rail pads; each pad carries half a sleeper, which rests
on a ballast block on the subgrade (the five-parameter ballasted track of Zhai, Wang & Lin
2004, without the shear coupling between neighbouring ballast blocks). Supports repeat every
``spacing_m``; the beam is cut into ``elements_per_bay`` finite elements per bay, so that a load
can stand over a sleeper, between two, or anywhere in ``elements_per_bay`` steps. Parameters and
their sources: ``docs/physics.md``.

What the vehicle model needs from the track:

- :func:`receptance`: the rail's vertical displacement per unit force at the wheel, averaged over
  the positions of a bay (a wheel crosses every position), and the cross receptance at the
  distance of the bogie's other wheel on the same rail; complex, (n_freq,) each;
- :func:`static_profile`: the static deflection under a wheel load at each position in a bay
  (deeper between sleepers than over one): a wheel rolling at constant load follows it, so it
  enters the model as an equivalent irregularity that repeats every sleeper;
- :meth:`TrackModel.support_stiffness`: the static stiffness of one support, from which the
  world scales the deflection where the supports differ from nominal (soft ballast, a voided
  sleeper, a bridge deck).

>>> w = static_profile(TrackModel(), 54_500.0)
>>> bool(0.3e-3 < w.mean() < 2.0e-3), bool(w[len(w) // 2] > w[0])  # mm; deeper mid-bay
(True, True)
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_banded

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


@dataclass(frozen=True)
class TrackModel:
    """A ballasted track with UIC60 rail on concrete sleepers (values: ``docs/physics.md``)."""

    # Rail: UIC60 (EN 13674-1).
    rail_mass_kg_m: float = 60.21
    rail_E_pa: float = 2.1e11
    rail_I_m4: float = 3.038e-5  # about the horizontal axis
    rail_area_m2: float = 7.67e-3
    rail_G_pa: float = 8.1e10
    rail_shear_coefficient: float = 0.38
    rail_loss_factor: float = 0.02
    # Rail pad, sleeper (half), ballast block, subgrade: per support, per rail.
    pad_stiffness_n_m: float = 6.5e7
    pad_damping_ns_m: float = 7.5e4
    sleeper_mass_kg: float = 125.5
    spacing_m: float = 0.6
    ballast_stiffness_n_m: float = 1.3775e8
    ballast_damping_ns_m: float = 5.88e4
    ballast_mass_kg: float = 531.4
    subgrade_stiffness_n_m: float = 7.75e7
    subgrade_damping_ns_m: float = 3.115e4
    # The finite-element model: bays each side of the load and elements per bay.
    bays: int = 40
    elements_per_bay: int = 8

    def support_stiffness(self, ballast_scale: float | FloatArray = 1.0) -> FloatArray:
        """Static stiffness (N/m) of one support at the rail: pad, ballast and subgrade in
        series, the ballast and subgrade scaled by ``ballast_scale`` (a stiffer bed, a bridge
        deck: > 1; a soft or voided one: < 1)."""
        below = 1.0 / (ballast_scale * self.ballast_stiffness_n_m) \
            + 1.0 / (ballast_scale * self.subgrade_stiffness_n_m)
        return np.asarray(1.0 / (1.0 / self.pad_stiffness_n_m + below), dtype=float)

    def support_impedance(self, omega: FloatArray) -> ComplexArray:
        """Dynamic stiffness (N/m, complex) of one support seen from the rail at angular
        frequencies ``omega``: pad in series with (sleeper mass on (ballast spring in series
        with (ballast mass on the subgrade)))."""
        w = np.asarray(omega, dtype=float)
        pad = self.pad_stiffness_n_m + 1j * w * self.pad_damping_ns_m
        ballast = self.ballast_stiffness_n_m + 1j * w * self.ballast_damping_ns_m
        ground = self.subgrade_stiffness_n_m + 1j * w * self.subgrade_damping_ns_m \
            - w**2 * self.ballast_mass_kg
        lower = _series(ballast, ground) - w**2 * self.sleeper_mass_kg
        return _series(pad, lower)


def _series(a: ComplexArray, b: ComplexArray) -> ComplexArray:
    """Two dynamic stiffnesses in series."""
    return a * b / (a + b)


def _element(track: TrackModel, length: float) -> tuple[FloatArray, FloatArray]:
    """Stiffness and mass matrices (4, 4) of one Timoshenko beam element, DOFs (w1, θ1, w2, θ2):
    the shear-deformable stiffness (Przemieniecki) and the consistent translational mass with
    the rotary inertia ρI."""
    E, I, L = track.rail_E_pa, track.rail_I_m4, length
    phi = 12 * E * I / (track.rail_shear_coefficient * track.rail_G_pa * track.rail_area_m2 * L**2)
    k = E * I / (L**3 * (1 + phi)) * np.array([
        [12, 6 * L, -12, 6 * L],
        [6 * L, (4 + phi) * L**2, -6 * L, (2 - phi) * L**2],
        [-12, -6 * L, 12, -6 * L],
        [6 * L, (2 - phi) * L**2, -6 * L, (4 + phi) * L**2]])
    m = track.rail_mass_kg_m * L / 420 * np.array([
        [156, 22 * L, 54, -13 * L],
        [22 * L, 4 * L**2, 13 * L, -3 * L**2],
        [54, 13 * L, 156, -22 * L],
        [-13 * L, -3 * L**2, -22 * L, 4 * L**2]])
    rho_i = track.rail_mass_kg_m / track.rail_area_m2 * I
    m = m + rho_i / (30 * L) * np.array([
        [36, 3 * L, -36, 3 * L],
        [3 * L, 4 * L**2, -3 * L, -L**2],
        [-36, -3 * L, 36, -3 * L],
        [3 * L, -L**2, -3 * L, 4 * L**2]])
    return k, m


def _banded(track: TrackModel) -> tuple[FloatArray, FloatArray, NDArray[np.int64], int]:
    """The rail's stiffness and mass in banded storage (7, n_dof) for ``solve_banded`` with
    three bands each side, the support nodes, and the node of the model's centre sleeper."""
    per = track.elements_per_bay
    n_el = 2 * track.bays * per
    n_dof = 2 * (n_el + 1)
    k, m = _element(track, track.spacing_m / per)
    kb = np.zeros((7, n_dof))
    mb = np.zeros((7, n_dof))
    for e in range(n_el):  # banded: ab[3 + i − j, j] = A[i, j]
        base = 2 * e
        for i in range(4):
            for j in range(4):
                kb[3 + i - j, base + j] += k[i, j]
                mb[3 + i - j, base + j] += m[i, j]
    supports = np.arange(0, n_el + 1, per)
    return kb, mb, supports, track.bays * per


@lru_cache(maxsize=16)
def _receptance_cached(track: TrackModel, freqs: tuple[float, ...], cross_m: float) -> tuple[
        ComplexArray, ComplexArray]:
    kb, mb, supports, centre = _banded(track)
    per = track.elements_per_bay
    n_dof = kb.shape[1]
    loads = centre + np.arange(per)  # every position of the bay right of the centre sleeper
    cross = int(round(cross_m / (track.spacing_m / per)))
    rhs = np.zeros((n_dof, per), dtype=complex)
    rhs[2 * loads, np.arange(per)] = 1.0
    out_self = np.empty(len(freqs), dtype=complex)
    out_cross = np.empty(len(freqs), dtype=complex)
    eta = 1 + 1j * track.rail_loss_factor
    for i, f in enumerate(freqs):
        w = 2 * np.pi * f
        ab = kb * eta - w**2 * mb + 0j
        ab[3, 2 * supports] += track.support_impedance(np.array([w]))[0]
        x = solve_banded((3, 3), ab, rhs, check_finite=False)
        out_self[i] = x[2 * loads, np.arange(per)].mean()
        out_cross[i] = x[2 * (loads + cross), np.arange(per)].mean() if cross else 0.0
    return out_self, out_cross


def receptance(track: TrackModel, freqs_hz: FloatArray,
               cross_m: float = 0.0) -> tuple[ComplexArray, ComplexArray]:
    """The rail's point receptance (m/N, complex) at ``freqs_hz``, averaged over the positions
    of a bay, and its cross receptance at ``cross_m`` further along (0: none). The model is
    ``bays`` sleepers each side of the load (waves die out well before its ends: the rail pads
    damp them), so its ends do not matter."""
    if cross_m < 0 or cross_m > track.bays * track.spacing_m / 2:
        raise ValueError(f"cross_m {cross_m:g} m is outside the track model")
    return _receptance_cached(track, tuple(float(f) for f in freqs_hz), float(cross_m))


def static_profile(track: TrackModel, load_n: float) -> FloatArray:
    """Static deflection (m, downwards positive) under ``load_n`` at each of the
    ``elements_per_bay`` positions of a bay, the first over a sleeper."""
    kb, _, supports, centre = _banded(track)
    per = track.elements_per_bay
    ab = kb.copy()
    ab[3, 2 * supports] += track.support_stiffness()
    rhs = np.zeros((kb.shape[1], per))
    loads = centre + np.arange(per)
    rhs[2 * loads, np.arange(per)] = load_n
    x = solve_banded((3, 3), ab, rhs, check_finite=False)
    return np.asarray(x[2 * loads, np.arange(per)], dtype=float)

