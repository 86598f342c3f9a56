"""Where the linear contact does not hold: the wheel leaves the rail and lands again.

The coupled model (:mod:`~railwatch.physics.dynamics`) joins wheel and rail by a spring
linearised at the static wheel load ``P0``. Over a dip that the wheel cannot follow (a squat's
edge, a joint's gap, a broken rail's step, a deep flat) that spring would pull the wheel down
with a tensile force: in truth the wheel flies, and lands with an impact. The true contact force
is Hertz's, ``F = (δ / G)^{3/2}`` for a compression δ > 0 and 0 for δ ≤ 0.

:func:`correct` finds the true force where the linear one fails. The linear solution gives each
contact's compression ``δ₀ + δ_lin(t)``; a force ``ΔF`` beyond the linear spring's moves the
wheel up and the rail down, by the responses of a **surrogate** of the contact's two sides: the
wheel's effective mass on the primary suspension, and the rail as a lumped mass on a pad on a
sleeper mass on the ballast, fitted to the finite-element rail's receptance
(:func:`~railwatch.physics.dynamics.contact_surrogate`). Stepped at :data:`SUBSTEPS` times the
simulation's rate (the contact's own resonance, kHz, well resolved), explicitly:

    ΔF = F_Hertz(δ₀ + δ_lin + Δδ) − P0 − k_H·δ_lin,    Δδ = −(wheel up + rail down)

wherever the linear wheel load falls below :data:`NEAR_LOSS` of the static one, from a little
before to a little after. To the coupled linear system the departure acts as a force pair at
the contact (up on the wheel, down on the rail) besides its linear spring,
``e = ΔF − k_H·Δδ``, which the caller turns into the sensors' response. Contacts are solved
each on its own; what one wheel's impact does to another's load is left to the linear model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: A contact is solved with Hertz's law where the linear wheel load falls below this share of
#: the static load.
NEAR_LOSS = 0.3
#: Seconds solved before the first and after the last sample below NEAR_LOSS.
BEFORE_S, AFTER_S = 0.002, 0.03
#: Integration steps per sample of the simulation's rate.
SUBSTEPS = 8


@dataclass(frozen=True)
class Hertz:
    """A Hertz contact at static load ``p0`` (N) with constant ``g`` (m/N^(2/3))."""

    p0: float
    g: float

    @property
    def delta0(self) -> float:
        """Static compression (m)."""
        return float(self.g * self.p0 ** (2 / 3))

    @property
    def stiffness(self) -> float:
        """Linearised stiffness at the static load (N/m)."""
        return 1.5 * self.p0 / self.delta0


@dataclass(frozen=True)
class Surrogate:
    """The two sides of a contact as lumped models (SI units): the wheel's effective mass on
    its suspension; the rail's effective mass on a pad on a sleeper on the ballast."""

    wheel_mass: float
    wheel_stiffness: float
    wheel_damping: float
    rail_mass: float
    pad_stiffness: float
    pad_damping: float
    sleeper_mass: float
    ballast_stiffness: float
    ballast_damping: float

    def receptance(self, f: FloatArray) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
        """(wheel, rail) receptances (m/N) at ``f`` Hz: what :func:`correct` integrates."""
        w = 2 * np.pi * np.asarray(f, dtype=float)
        wheel = 1 / (self.wheel_stiffness + 1j * w * self.wheel_damping - w**2 * self.wheel_mass)
        pad = self.pad_stiffness + 1j * w * self.pad_damping
        below = self.ballast_stiffness + 1j * w * self.ballast_damping - w**2 * self.sleeper_mass
        rail = 1 / (pad * below / (pad + below) - w**2 * self.rail_mass)
        return np.asarray(wheel, dtype=complex), np.asarray(rail, dtype=complex)


@dataclass
class Correction:
    """The force pair ``e`` (N, per contact and sample) and what happened: where a wheel left
    the rail (contact, sample), each solved stretch's highest wheel load (sample, N), and
    which samples were solved."""

    e: FloatArray  # (n_contacts, n)
    lost: list[tuple[int, int]]
    peaks: list[tuple[int, float]]
    solved: NDArray[np.bool_]  # (n_contacts, n)


def windows(load_ratio: FloatArray, fs: float) -> list[tuple[int, int]]:
    """Stretches (start, stop) of samples to solve: where ``load_ratio`` (the linear wheel load
    over the static) is below :data:`NEAR_LOSS`, widened by BEFORE_S and AFTER_S, overlapping
    ones merged."""
    low = np.flatnonzero(load_ratio < NEAR_LOSS)
    if not len(low):
        return []
    before, after = int(round(BEFORE_S * fs)), int(round(AFTER_S * fs))
    cuts = np.flatnonzero(np.diff(low) > before + after) + 1
    out: list[tuple[int, int]] = []
    for group in np.split(low, cuts):
        start = max(int(group[0]) - before, 0)
        stop = min(int(group[-1]) + after + 1, len(load_ratio))
        if out and start <= out[-1][1]:
            out[-1] = (out[-1][0], stop)
        else:
            out.append((start, stop))
    return out


def correct(delta_lin: FloatArray, surrogate: Surrogate, hertz: Hertz, fs: float) -> Correction:
    """Solve the contacts with Hertz's law where the linear spring fails (module docstring).

    ``delta_lin`` (n_contacts, n): each linear spring's dynamic compression (m) at rate ``fs``.
    All stretches of all contacts are stepped together, as one batch.
    """
    n_c, n = delta_lin.shape
    k_h = hertz.stiffness
    spans = [(c, a, b) for c in range(n_c)
             for a, b in windows(1.0 + k_h * delta_lin[c] / hertz.p0, fs)]
    e = np.zeros((n_c, n))
    solved = np.zeros((n_c, n), dtype=bool)
    if not spans:
        return Correction(e=e, lost=[], peaks=[], solved=solved)
    length = max(b - a for _, a, b in spans)
    # Each stretch's linear compression at the sub-steps (linear between samples; held after
    # its end, where nothing is used).
    steps = length * SUBSTEPS
    grid = np.arange(steps) / SUBSTEPS
    lin = np.empty((len(spans), steps))
    for i, (c, a, b) in enumerate(spans):
        lin[i] = np.interp(grid, np.arange(b - a), delta_lin[c, a:b])
    dt = 1.0 / (fs * SUBSTEPS)
    s = surrogate
    k = len(spans)
    xw = np.zeros(k)  # wheel up
    vw = np.zeros(k)
    xr = np.zeros(k)  # rail down
    vr = np.zeros(k)
    xs = np.zeros(k)  # sleeper down
    vs = np.zeros(k)
    e_sub = np.empty((k, steps))
    load = np.empty((k, steps))
    for j in range(steps):  # symplectic Euler: forces from positions, then velocities, positions
        d_delta = -(xw + xr)
        total = hertz.delta0 + lin[:, j] + d_delta
        f_true = np.where(total > 0, (np.maximum(total, 0) / hertz.g) ** 1.5, 0.0)
        d_force = f_true - hertz.p0 - k_h * lin[:, j]
        e_sub[:, j] = d_force - k_h * d_delta
        load[:, j] = f_true
        pad = s.pad_stiffness * (xr - xs) + s.pad_damping * (vr - vs)
        vw += dt * (d_force - s.wheel_stiffness * xw - s.wheel_damping * vw) / s.wheel_mass
        vr += dt * (d_force - pad) / s.rail_mass
        vs += dt * (pad - s.ballast_stiffness * xs - s.ballast_damping * vs) / s.sleeper_mass
        xw += dt * vw
        xr += dt * vr
        xs += dt * vs
    lost: list[tuple[int, int]] = []
    for i, (c, a, b) in enumerate(spans):
        m = b - a
        e[c, a:b] = e_sub[i, : m * SUBSTEPS].reshape(m, SUBSTEPS).mean(axis=1)
        solved[c, a:b] = True
        off = load[i, : m * SUBSTEPS] <= 0
        starts = np.flatnonzero(off & ~np.concatenate([[False], off[:-1]]))
        lost += [(c, a + int(j) // SUBSTEPS) for j in starts]
    peaks = []
    for i, (_, a, b) in enumerate(spans):
        j = int(np.argmax(load[i, : (b - a) * SUBSTEPS]))
        peaks.append((a + j // SUBSTEPS, float(load[i, j])))
    return Correction(e=e, lost=sorted(lost, key=lambda t: t[1]), peaks=peaks, solved=solved)
