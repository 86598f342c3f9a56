"""A pass: the coach over a physics track at a speed profile, recorded as a field logger would.

Under each of the coach's eight wheels the track's wheel path is sampled at the internal rate
``fs_sim`` (a multiple of the recording's ``fs``, at least 8 kHz; each sample is the path's mean
over the distance the wheel rolled in it, so rail wavelengths shorter than a sample do not
alias), the wheel's own out-of-roundness and flat added. The coupled vehicle–track transfer
functions (:mod:`~railwatch.physics.dynamics`) turn these eight inputs into contact forces and
the six sensors' accelerations; where a wheel's load falls towards zero the contact is solved
with Hertz's law, the wheel free to leave the rail (:mod:`~railwatch.physics.contact`); the
data acquisition's filters (AC coupling, the anti-alias low-pass) are applied and the signal is
sampled at ``fs``; each sensor's noise is added.

The same pass over the track's clean twin, without the sensor noise, is the pass's **clean
twin**: what the pass would have recorded without its defects and its sensor noise (same speed,
same wheels, same features). Away from the defects the two differ by the noise alone.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import fft as sfft

from railwatch.errors import RailwatchError
from railwatch.physics.contact import correct
from railwatch.physics.dynamics import Coupling, contact_surrogate, coupled, hertz, on_bins
from railwatch.physics.features import Item
from railwatch.physics.vehicle import CHANNELS
from railwatch.physics.world import DX_M, PhysicsTrack, Sensors, World

FloatArray = NDArray[np.float64]
log = logging.getLogger(__name__)

#: Seconds simulated before and after the recording, so that the coach is in motion on the
#: track when the recording starts and the transform's wrap-around never reaches it.
LEAD_S = 4.0
#: The lowest internal rate (Hz): the contact's resonance (P1, about 1 kHz) well resolved.
MIN_SIM_RATE = 8000.0
#: Frequency bins per block when contact forces are computed (bounds the memory).
BLOCK = 1 << 17


@dataclass(frozen=True)
class PassPlan:
    """One pass: its direction (+1 along increasing position), whether the coach runs back
    without turning (``push_pull``: its front stays towards +x), its speed range (m/s) and the
    recording's rate (Hz)."""

    direction: int = 1
    push_pull: bool = False
    speed_ms: tuple[float, float] = (10.0, 30.0)
    fs: float = 2000.0

    def check(self) -> None:
        lo, hi = self.speed_ms
        if self.direction not in (1, -1):
            raise RailwatchError(f"direction is 1 or -1, got {self.direction}")
        if not 1.0 <= lo <= hi <= 40.0:
            raise RailwatchError(f"speeds {lo:g}-{hi:g} m/s: give 1 <= low <= high <= 40 m/s "
                                 "(a 2-10 cm squat is crossed in 1-10 ms at 10-30 m/s)")
        if not 200.0 <= self.fs <= 20_000.0:
            raise RailwatchError(f"--fs {self.fs:g} Hz: give a rate of 200-20000 Hz (field "
                                 "recordings: 1-5 kHz)")

    @property
    def orientation(self) -> int:
        """+1 when the coach's front points along increasing position."""
        return 1 if self.push_pull else self.direction


@dataclass
class PhysicsPass:
    """A simulated pass: its columns (time, speed, true position, the six channels), its clean
    twin's, and when its sensors crossed every item."""

    fs: float
    columns: dict[str, NDArray[Any]]
    twin: dict[str, NDArray[Any]]
    crossings: list[dict[str, Any]]  # the defects
    features: list[dict[str, Any]]
    #: Where a wheel left the rail (true positions, m) and the highest wheel load over the
    #: static one.
    flights_m: list[float]
    peak_load: float


def oversampling(fs: float) -> int:
    """The internal rate's multiple of the recording's ``fs``: at least 2, and at least
    :data:`MIN_SIM_RATE`."""
    return max(2, int(np.ceil(MIN_SIM_RATE / fs)))


def speed_profile(rng: np.random.Generator, distance_m: float,
                  speed_ms: tuple[float, float]) -> tuple[FloatArray, FloatArray]:
    """Speed against distance travelled: a new target speed every 0.5–1.5 km, drawn uniformly
    in ``speed_ms`` and reached with v² linear in distance (a constant acceleration, at most
    0.8 m/s² between 10 and 30 m/s). Returns (distance knots m, speeds m/s)."""
    knots = [0.0]
    while knots[-1] < distance_m:
        knots.append(knots[-1] + float(rng.uniform(500.0, 1500.0)))
    return np.asarray(knots), rng.uniform(speed_ms[0], speed_ms[1], len(knots))


def speed_at(s: FloatArray, knots: FloatArray, speeds: FloatArray) -> FloatArray:
    return np.sqrt(np.interp(s, knots, speeds**2))


def simulate_pass(track: PhysicsTrack, plan: PassPlan, seed: int,
                  coupling: Coupling | None = None) -> PhysicsPass:
    """One pass of the coach over ``track`` (module docstring): it enters up to 200 m from its
    end (uniformly; up to a quarter of a track shorter than 800 m) and runs to within as much
    of the other end."""
    plan.check()
    world = track.world
    vehicle = world.vehicle
    rng = np.random.default_rng([seed, 400])
    q = oversampling(plan.fs)
    fs_sim = q * plan.fs
    coupling = coupling or coupled(vehicle, world.track, fs_sim / 2)
    if coupling.f_max < fs_sim / 2:
        raise RailwatchError(f"the coupling is solved to {coupling.f_max:g} Hz, the pass needs "
                             f"{fs_sim / 2:g} Hz")

    # Where the sensor wheelset is: distance travelled s against time, with lead-in and -out.
    enter, leave = rng.uniform(0.0, min(200.0, world.length_m / 4), 2)
    distance = world.length_m - enter - leave
    knots, speeds = speed_profile(rng, distance, plan.speed_ms)
    lead_out = LEAD_S * speed_at(np.array([distance]), knots, speeds)[0]
    grid = np.arange(-LEAD_S * speeds[0], distance + lead_out + 1.0, 0.5)
    v_grid = speed_at(np.clip(grid, 0, distance), knots, speeds)
    t_grid = np.concatenate([[0.0], np.cumsum(np.diff(grid) / v_grid[:-1])])
    t_start, t_end = np.interp([0.0, distance], grid, t_grid)
    n_sim = int(np.floor(t_grid[-1] * fs_sim))
    n_fft = q * sfft.next_fast_len(int(np.ceil(n_sim / q)), real=True)
    half = 0.5 / fs_sim
    t_sim = np.arange(n_sim) / fs_sim
    s_edges = np.interp(np.concatenate([t_sim - half, [t_sim[-1] + half]]), t_grid, grid)
    s_mid = 0.5 * (s_edges[1:] + s_edges[:-1])
    start_x = enter if plan.direction == 1 else world.length_m - enter
    o = plan.orientation
    rails = [(c % 2) if o == 1 else 1 - (c % 2) for c in range(8)]  # vehicle left: rail 1 if o=+1
    wheels = _wheel_deviation(world, s_mid, rng, np.random.default_rng([track.seed, 500]))
    # The inputs fade in over the lead-in's first second and out over the lead-out's last.
    ramp = np.clip(np.minimum(t_sim, t_sim[-1] - t_sim), 0.0, 1.0)
    taper = 0.5 * (1 - np.cos(np.pi * ramp))
    recorded = (t_sim >= t_start) & (t_sim <= t_end)

    bins = sfft.rfftfreq(n_fft, 1 / fs_sim)
    n_out_fft = n_fft // q
    band = bins[: n_out_fft // 2 + 1]
    to_sensors = on_bins(coupling.freqs, coupling.sensor_transfer, band)
    per_force = on_bins(coupling.freqs, coupling.sensor_per_force, band)
    surrogate = contact_surrogate(vehicle, world.track)
    contact = hertz(vehicle)
    daq = _daq_response(band, plan.fs, world.sensors)
    out: dict[bool, FloatArray] = {}
    flights: list[float] = []
    peak = 0.0
    for clean in (False, True):
        cum = track.cumulative(clean)
        r = np.empty((8, n_sim))
        for c in range(8):
            x_edges = start_x + plan.direction * s_edges + o * vehicle.contact_x_m[c]
            r[c] = _mean_over(cum[rails[c]], x_edges, track.x0) + wheels[c]
        del cum
        r = (r - r.mean(axis=1, keepdims=True)) * taper  # no jump where the transform wraps
        spec = sfft.rfft(r, n_fft, axis=1)
        del r
        force = np.empty((8, len(bins)), dtype=complex)
        for a in range(0, len(bins), BLOCK):
            t = on_bins(coupling.freqs, coupling.force_transfer, bins[a:a + BLOCK])
            force[:, a:a + BLOCK] = np.einsum("fck,kf->cf", t, spec[:, a:a + BLOCK])
        delta = sfft.irfft(force, n_fft, axis=1)[:, :n_sim] / contact.stiffness
        del force
        fix = correct(delta, surrogate, contact, fs_sim)
        y = np.einsum("fok,kf->of", to_sensors, spec[:, : len(band)])
        if fix.lost or fix.e.any():
            y += np.einsum("fok,kf->of", per_force,
                           sfft.rfft(fix.e, n_fft, axis=1)[:, : len(band)])
        out[clean] = sfft.irfft(y * daq, n_out_fft, axis=1) / q
        if not clean:
            flights = sorted(start_x + plan.direction * s_mid[i] for _, i in fix.lost
                             if recorded[i])
            # The highest wheel load while recording: Hertz's where solved, else the linear.
            solved = np.where(fix.solved | ~recorded, -np.inf, delta).max()
            hertz_peak = max([f for i, f in fix.peaks if recorded[i]], default=0.0)
            peak = max(hertz_peak, contact.p0 + contact.stiffness * solved) / contact.p0

    first = int(np.ceil(t_start * plan.fs))
    n_rec = int(np.floor((t_end - t_start) * plan.fs)) + 1
    rec = slice(first, first + n_rec)
    t_out = np.arange(n_out_fft)[rec] / plan.fs
    s_out = np.interp(t_out, t_grid, grid)
    true = start_x + plan.direction * s_out
    speed = speed_at(np.clip(s_out, 0, distance), knots, speeds)
    time = t_out - t_out[0]
    sigma = world.sensors.noise()
    noise = sigma[:, None] * np.random.default_rng([seed, 401]).standard_normal((6, n_rec))
    columns: dict[str, NDArray[Any]] = {"time": time, "speed": speed, "position": true}
    twin: dict[str, NDArray[Any]] = {**columns, "position": true.copy()}
    for i, name in enumerate(CHANNELS):
        columns[name] = (out[False][i, rec] + noise[i]).astype(np.float32)
        twin[name] = out[True][i, rec].astype(np.float32)
    if flights:
        log.debug("a wheel left the rail at %d places (first at %.0f m)", len(flights),
                 flights[0])
    return PhysicsPass(fs=plan.fs, columns=columns, twin=twin,
                       crossings=crossings(track.defects, time, true, speed, o, plan.direction),
                       features=crossings(track.features, time, true, speed, o, plan.direction),
                       flights_m=flights, peak_load=float(peak))


def _mean_over(cum: FloatArray, x_edges: FloatArray, x0: float) -> FloatArray:
    """The path's mean between consecutive positions ``x_edges`` (n + 1,) from its running
    integral ``cum``: ``(C(x₁) − C(x₀)) / (x₁ − x₀)``."""
    u = (x_edges - x0) / DX_M
    if u.min() < 0 or u.max() > len(cum) - 2:
        raise RailwatchError("a wheel ran off the simulated rail: the pass is longer than its "
                             "track")
    i = np.floor(u).astype(np.int64)
    f = u - i
    c = cum[i] * (1 - f) + cum[i + 1] * f
    dx = np.diff(x_edges)
    return np.diff(c) / np.where(np.abs(dx) < 1e-12, 1e-12, dx)


def _wheel_deviation(world: World, s: FloatArray, rng: np.random.Generator,
                     vehicle_rng: np.random.Generator) -> FloatArray:
    """(8, n): each contact's wheel radius deviation (m) at distances rolled ``s``:
    out-of-roundness of orders 1-20 (the coach's own, from ``vehicle_rng``, rms ``oor_um / n``
    µm at order n; each wheel's angle at the pass's start from ``rng``) and the flat of
    ``world.flat_mm`` on the leading left wheel (a rounded flat ``d(1 − cos 2πu)/2`` over the
    chord of a new flat of that depth, ``√(8Rd)``)."""
    radius = world.vehicle.wheel_radius_m
    circumference = 2 * np.pi * radius
    orders = np.arange(1, 21)
    amps = world.oor_um * 1e-6 / orders * np.sqrt(2) * vehicle_rng.uniform(0.5, 1.5, (8, 20))
    phases = vehicle_rng.uniform(0, 2 * np.pi, (8, 20))
    start = rng.uniform(0, circumference, 8)
    arc = np.linspace(0.0, circumference, 4097)  # one turn, under 1 mm apart
    theta = arc / radius
    out = np.empty((8, len(s)))
    flat_len = np.sqrt(8 * radius * world.flat_mm * 1e-3)
    for c in range(8):
        table = (amps[c][:, None] * np.cos(orders[:, None] * theta + phases[c][:, None])).sum(0)
        if c == 0 and world.flat_mm > 0:
            u = arc / flat_len
            table -= world.flat_mm * 1e-3 * 0.5 * (1 - np.cos(2 * np.pi * u)) * (u < 1)
        out[c] = np.interp(s + start[c], arc, table, period=circumference)
    return out


def _daq_response(f: FloatArray, fs: float, sensors: Sensors) -> NDArray[np.complex128]:
    """The acquisition's filters: a first-order high-pass (AC coupling) and a zero-phase
    anti-alias low-pass, flat to ``passband`` · fs and rolling off as a cosine to fs / 2."""
    hp = 1j * f / (sensors.highpass_hz + 1j * f)
    edge, nyq = sensors.passband * fs, fs / 2
    lp = 0.5 * (1 + np.cos(np.pi * np.clip((f - edge) / (nyq - edge), 0, 1)))
    return np.asarray(hp * lp, dtype=complex)


def crossings(items: list[Item], time: FloatArray, true: FloatArray, speed: FloatArray,
              orientation: int, direction: int) -> list[dict[str, Any]]:
    """When the sensor wheelset crossed each item (the time it reached its start, and its
    centre, s), at what speed, and which axle-box channel ran on its rail."""
    lo, hi = min(true[0], true[-1]), max(true[0], true[-1])
    key = true * direction  # increasing along the pass
    rows: list[dict[str, Any]] = []
    for it in items:
        centre = it.position_m + it.length_m / 2
        if not lo <= centre <= hi:
            continue
        t_c = float(np.interp(centre * direction, key, time))
        entry = it.position_m if direction == 1 else it.end_m
        t_0 = float(np.interp(entry * direction, key, time))
        v = float(np.interp(t_c, time, speed))
        side = "" if it.rail == 0 else (
            "left" if (it.rail == 1) == (orientation == 1) else "right")
        rows.append({"defect": it.index, "kind": it.kind, "time_s": round(t_0, 6),
                     "duration_s": round(it.length_m / v, 6), "center_s": round(t_c, 6),
                     "position_m": round(it.position_m, 4), "length_m": round(it.length_m, 4),
                     "depth_mm": round(it.depth_mm, 4), "rail": it.rail,
                     "channel": f"axle_{side}" if side else "", "speed_ms": round(v, 3)})
    rows.sort(key=lambda row: row["time_s"])
    return rows
