"""Vehicle and track coupled at the eight wheel–rail contacts, in the frequency domain.

Each contact is a linearised Hertz spring (stiffness ``3/2 · P0^(1/3) / G`` at the static wheel
load ``P0``, with ``G`` the Hertz constant of a worn wheel tread on a rail, after Zhai); under it
the rail moves as its receptance says (each rail's two wheels of one bogie also move each
other's rail: the cross receptance). With ``r`` the irregularity under each contact (the rail's
height, less the wheel's out-of-roundness; upwards positive), ``F`` the dynamic contact forces
(upwards on the wheels) and ``q`` the vehicle's 17 coordinates, at angular frequency ω::

    [ Dᵥ(ω)   −B        ] [q]   [0]
    [ Bᵀ      1/k_H + A ] [F] = [r]

with ``Dᵥ = K + iωC − ω²M`` the vehicle's dynamic stiffness, ``B`` the contacts
(:meth:`~railwatch.physics.vehicle.Vehicle.contacts`) and ``A`` the rail receptances. The sensors
see ``−ω² Sᵀ q``. The system is linear and time-invariant, so a pass at any speed profile is its
irregularity under each wheel (a function of time) through :class:`Coupling`'s transfer
functions. What this leaves out (the wheel's own modes, loss of contact, the support's position
under the wheel beyond the static deflection it causes): ``docs/physics.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from railwatch.physics.contact import Hertz, Surrogate
from railwatch.physics.track import TrackModel, receptance
from railwatch.physics.vehicle import Vehicle

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

#: Hertz constant G of a worn wheel tread on a rail: G = 3.86·R^(−0.115)·1e−8 m/N^(2/3) (R the
#: wheel's radius in m; Zhai, Vehicle–track coupled dynamics; 4.57·R^(−0.149) for a conical
#: tread).
HERTZ_G_COEFFICIENT = 3.86e-8
HERTZ_G_EXPONENT = -0.115


def hertz(vehicle: Vehicle) -> Hertz:
    """The wheel–rail contact of ``vehicle``'s wheels at their static load."""
    return Hertz(vehicle.static_wheel_load_n,
                 HERTZ_G_COEFFICIENT * vehicle.wheel_radius_m ** HERTZ_G_EXPONENT)


def hertz_stiffness(vehicle: Vehicle) -> float:
    """The contact's stiffness (N/m) linearised at the static wheel load."""
    return hertz(vehicle).stiffness


def frequency_grid(f_max: float) -> FloatArray:
    """Where the transfer functions are solved (Hz): every 5 mHz up to 2 Hz (the car body's
    modes, 0.2 Hz wide), then 0.2 % apart up to ``f_max`` (a resonance with 0.1 % damping is
    still two points wide)."""
    low = np.arange(0.0, 2.0, 0.005)
    high = np.geomspace(2.0, f_max, int(np.ceil(np.log(f_max / 2.0) / np.log(1.002))) + 1)
    return np.concatenate([low, high])


@dataclass(frozen=True)
class Coupling:
    """The coupled vehicle–track system's transfer functions on :func:`frequency_grid`."""

    vehicle: Vehicle
    track: TrackModel
    f_max: float = 4_000.0

    @cached_property
    def freqs(self) -> FloatArray:
        return frequency_grid(self.f_max)

    @cached_property
    def _solved(self) -> tuple[ComplexArray, ComplexArray]:
        v, f = self.vehicle, self.freqs
        m, k, c = v.matrices()
        b = v.contacts()  # (17, 8)
        s = v.sensors()  # (17, 6)
        # The rail's receptance on a coarser grid, interpolated: it is smooth in log frequency.
        coarse = np.concatenate([[0.0], np.geomspace(0.1, self.f_max, 500)])
        a_self, a_cross = receptance(self.track, coarse, cross_m=2 * v.semi_wheelbase_m)
        a_self, a_cross = (np.interp(f, coarse, a.real) + 1j * np.interp(f, coarse, a.imag)
                           for a in (a_self, a_cross))
        n = len(f)
        w = 2 * np.pi * f
        big = np.zeros((n, 25, 25), dtype=complex)
        big[:, :17, :17] = k[None] + 1j * w[:, None, None] * c[None] - w[:, None, None] ** 2 * m
        big[:, :17, 17:] = -b[None]
        big[:, 17:, :17] = b.T[None]
        contact = np.arange(8)
        big[:, 17 + contact, 17 + contact] = 1.0 / hertz_stiffness(v) + a_self[:, None]
        for lead in (0, 1, 4, 5):  # the same rail's wheels of one bogie: wheelsets 0-1, 2-3
            big[:, 17 + lead, 19 + lead] = a_cross
            big[:, 19 + lead, 17 + lead] = a_cross
        # Right-hand sides: a unit irregularity under each contact, then a unit force pair at
        # each contact (up on the wheel, down on the rail) besides the linear contact spring.
        rhs = np.zeros((n, 25, 16), dtype=complex)
        rhs[:, 17 + contact, contact] = 1.0
        rhs[:, :17, 8:] = b[None]
        rhs[:, 17:, 8:] = -big[:, 17:, 17:] + (1.0 / hertz_stiffness(v)) * np.eye(8)[None]
        x = np.linalg.solve(big, rhs)  # (n, 25, 16)
        sensors = -(w**2)[:, None, None] * np.einsum("dc,ndk->nck", s, x[:, :17, :])
        return np.asarray(sensors, dtype=complex), np.asarray(x[:, 17:, :], dtype=complex)

    @property
    def sensor_transfer(self) -> ComplexArray:
        """(n_freq, 6, 8): sensor acceleration (m/s²) per metre of irregularity under each
        contact."""
        return self._solved[0][:, :, :8]

    @property
    def force_transfer(self) -> ComplexArray:
        """(n_freq, 8, 8): dynamic contact force (N, upwards on the wheel) per metre of
        irregularity under each contact."""
        return self._solved[1][:, :, :8]

    @property
    def sensor_per_force(self) -> ComplexArray:
        """(n_freq, 6, 8): sensor acceleration per newton of a force pair at each contact (up
        on its wheel, down on its rail) acting besides the linear contact spring: how a
        contact force that departs from the linear spring's moves the sensors."""
        return self._solved[0][:, :, 8:]

@lru_cache(maxsize=8)
def coupled(vehicle: Vehicle, track: TrackModel, f_max: float) -> Coupling:
    """The :class:`Coupling` of ``vehicle`` and ``track`` up to ``f_max`` Hz, solved once."""
    coupling = Coupling(vehicle, track, f_max)
    coupling.sensor_transfer  # noqa: B018 - solve now, once
    return coupling


def on_bins(freqs: FloatArray, transfer: ComplexArray, bins: FloatArray) -> ComplexArray:
    """``transfer`` (n_freq, ...) interpolated onto the frequencies ``bins`` (complex, linear in
    frequency; beyond the grid's top: 0)."""
    flat = transfer.reshape(len(freqs), -1)
    j = np.clip(np.searchsorted(freqs, bins, side="right") - 1, 0, len(freqs) - 2)
    t = np.clip((bins - freqs[j]) / (freqs[j + 1] - freqs[j]), 0.0, 1.0)[:, None]
    out = flat[j] * (1 - t) + flat[j + 1] * t
    out[bins > freqs[-1]] = 0.0
    return out.reshape((len(bins), *transfer.shape[1:]))


@lru_cache(maxsize=8)
def contact_surrogate(vehicle: Vehicle, track: TrackModel) -> Surrogate:
    """The lumped models :func:`~railwatch.physics.contact.correct` steps: the wheel's mass,
    stiffness and damping as seen at its contact point (the wheelset's bounce and roll on its
    two axle boxes), and a rail mass on a pad on a sleeper mass on the ballast whose receptance
    is fitted (least squares on log magnitude and phase, 100-3000 Hz, where impacts ring) to
    the finite-element rail's."""
    y, yp = vehicle.contact_y_m, vehicle.primary_y_m
    # A force at the contact point: bounce 1/m plus roll y²/J (mass); springs at ±yp.
    mass = 1 / (1 / vehicle.wheelset_mass_kg + y**2 / vehicle.wheelset_roll_kgm2)
    per_spring = 1 / (1 / 2 + y**2 / (2 * yp**2))
    f = np.geomspace(100.0, 3000.0, 120)
    target, _ = receptance(track, f)
    w = 2 * np.pi * f

    def model(p: FloatArray) -> ComplexArray:
        mr, kp, cp, ms, kb, cb = np.exp(p)
        below = kb + 1j * w * cb - w**2 * ms
        pad = kp + 1j * w * cp
        return 1 / (pad * below / (pad + below) - w**2 * mr)

    def residual(p: FloatArray) -> FloatArray:
        ratio = model(p) / target
        return np.concatenate([np.log(np.abs(ratio)), np.angle(ratio)])

    start = np.log([10.0, 2 * track.pad_stiffness_n_m, track.pad_damping_ns_m,
                    2 * track.sleeper_mass_kg, float(track.support_stiffness()), 1e5])
    mr, kp, cp, ms, kb, cb = np.exp(least_squares(residual, start).x)
    return Surrogate(wheel_mass=mass,
                     wheel_stiffness=per_spring * vehicle.primary_stiffness_n_m,
                     wheel_damping=per_spring * vehicle.primary_damping_ns_m,
                     rail_mass=mr, pad_stiffness=kp, pad_damping=cp, sleeper_mass=ms,
                     ballast_stiffness=kb, ballast_damping=cb)

