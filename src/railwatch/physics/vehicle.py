"""The vehicle: a passenger coach in vertical motion and roll, and where its sensors sit.

Seventeen degrees of freedom (the Manchester benchmark coach, Iwnicki 1998; values and their
sources in ``docs/physics.md``): the car body's bounce, pitch and roll; each of its two bogie
frames' bounce, pitch and roll; each of four wheelsets' bounce and roll. Springs and dampers in
parallel join points of two bodies: the secondary suspension (car body to bogie frame, one each
side of each bogie) and the primary suspension (bogie frame to wheelset, one at each axle box).
Gravity is balanced by the static deflections: the model moves about its static equilibrium.

A point of a body at longitudinal ``x`` (forwards positive) and lateral ``y`` (left positive)
moves vertically by ``z + x·θ + y·φ``; :func:`point` gives the row that maps the 17 coordinates
to it. The wheels touch the rails at ``y = ±contact_y_m`` (8 contacts, ordered wheelset by
wheelset, left wheel first); the six sensors (the layout's channels, in order) are:

====== ====================================================================
axle   the leading wheelset's axle boxes, left and right (primary spring ends)
bogie  the leading bogie's frame above that wheelset, left and right
body   the car body's floor above the leading bogie's centre, left and right
====== ====================================================================
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: The recording's channels (vehicle left and right) and their sensor groups, in order.
CHANNELS = ("axle_left", "axle_right", "bogie_left", "bogie_right", "body_left", "body_right")
GROUPS = ("axle", "axle", "bogie", "bogie", "body", "body")
N_DOF = 17
GRAVITY = 9.81


@dataclass(frozen=True)
class Vehicle:
    """The Manchester benchmark coach (Iwnicki 1998), vertical and roll parameters."""

    body_mass_kg: float = 32_000.0
    body_pitch_kgm2: float = 1.97e6
    body_roll_kgm2: float = 5.68e4
    bogie_mass_kg: float = 2_615.0
    bogie_pitch_kgm2: float = 1_476.0
    bogie_roll_kgm2: float = 1_722.0
    wheelset_mass_kg: float = 1_813.0
    wheelset_roll_kgm2: float = 1_120.0
    primary_stiffness_n_m: float = 1.22e6  # vertical, per axle box
    primary_damping_ns_m: float = 4.0e3
    secondary_stiffness_n_m: float = 4.3e5  # vertical, per side of a bogie
    secondary_damping_ns_m: float = 2.0e4
    bogie_semi_spacing_m: float = 9.5  # body centre to bogie centre
    semi_wheelbase_m: float = 1.28  # bogie centre to wheelset
    primary_y_m: float = 1.0  # lateral semi-spacing of the axle boxes
    secondary_y_m: float = 1.0  # lateral semi-spacing of the secondary springs
    contact_y_m: float = 0.75  # half the distance between the wheels' contact points
    wheel_radius_m: float = 0.46

    @property
    def static_wheel_load_n(self) -> float:
        """The static load of one wheel on its rail (N): the whole coach on eight wheels."""
        mass = self.body_mass_kg + 2 * self.bogie_mass_kg + 4 * self.wheelset_mass_kg
        return mass * GRAVITY / 8

    @property
    def wheelset_x_m(self) -> FloatArray:
        """Longitudinal position of each wheelset from the body's centre (m), leading first."""
        a, b = self.bogie_semi_spacing_m, self.semi_wheelbase_m
        return np.array([a + b, a - b, -a + b, -a - b])

    @property
    def contact_x_m(self) -> FloatArray:
        """Longitudinal position of each of the 8 contacts from the leading wheelset (m)."""
        x = self.wheelset_x_m - self.wheelset_x_m[0]
        return np.repeat(x, 2)

    @property
    def contact_y_m_each(self) -> FloatArray:
        """Lateral position of each contact (left positive)."""
        return np.tile([self.contact_y_m, -self.contact_y_m], 4)

    def matrices(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Mass, stiffness and damping matrices (17, 17) about static equilibrium."""
        m = np.diag([self.body_mass_kg, self.body_pitch_kgm2, self.body_roll_kgm2,
                     *[self.bogie_mass_kg, self.bogie_pitch_kgm2, self.bogie_roll_kgm2] * 2,
                     *[self.wheelset_mass_kg, self.wheelset_roll_kgm2] * 4])
        k = np.zeros((N_DOF, N_DOF))
        c = np.zeros((N_DOF, N_DOF))
        a, b = self.bogie_semi_spacing_m, self.semi_wheelbase_m
        for i, xb in enumerate((a, -a)):
            for y in (self.secondary_y_m, -self.secondary_y_m):
                d = point("body", 0, xb, y) - point("bogie", i, 0.0, y)
                k += self.secondary_stiffness_n_m * np.outer(d, d)
                c += self.secondary_damping_ns_m * np.outer(d, d)
            for j, xw in enumerate((b, -b)):
                for y in (self.primary_y_m, -self.primary_y_m):
                    d = point("bogie", i, xw, y) - point("wheelset", 2 * i + j, 0.0, y)
                    k += self.primary_stiffness_n_m * np.outer(d, d)
                    c += self.primary_damping_ns_m * np.outer(d, d)
        return m, k, c

    def contacts(self) -> FloatArray:
        """(17, 8): column c maps contact c's upward force to generalised forces, and its
        transpose maps the coordinates to the contact points' vertical displacements."""
        y = self.contact_y_m
        return np.stack([point("wheelset", j, 0.0, s) for j in range(4) for s in (y, -y)], axis=1)

    def sensors(self) -> FloatArray:
        """(17, 6): the vertical displacement of each sensor (:data:`CHANNELS`) from the
        coordinates."""
        a, b = self.bogie_semi_spacing_m, self.semi_wheelbase_m
        rows = []
        for y in (self.primary_y_m, -self.primary_y_m):
            rows.append(point("wheelset", 0, 0.0, y))
        for y in (self.primary_y_m, -self.primary_y_m):
            rows.append(point("bogie", 0, b, y))
        for y in (self.secondary_y_m, -self.secondary_y_m):
            rows.append(point("body", 0, a, y))
        return np.stack(rows, axis=1)


def point(body: str, index: int, x: float, y: float) -> FloatArray:
    """(17,): the vertical displacement of the point at (``x``, ``y``) of a body (``"body"``,
    ``"bogie"`` 0-1 or ``"wheelset"`` 0-3; a wheelset has no pitch)."""
    row = np.zeros(N_DOF)
    if body == "body":
        row[0:3] = (1.0, x, y)
    elif body == "bogie":
        row[3 + 3 * index:6 + 3 * index] = (1.0, x, y)
    elif body == "wheelset":
        row[9 + 2 * index:11 + 2 * index] = (1.0, y)
    else:
        raise ValueError(f"no body {body!r}")
    return row
