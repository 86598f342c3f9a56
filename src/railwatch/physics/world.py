"""A physics world: one track with defects and features, and passes of one coach over it.

**The track** (:func:`build_track`) is each rail's height along the line, on a 1-mm grid that
runs :data:`MARGIN_M` beyond both ends (the line goes on; a pass starts and ends on it):

1. the long-wave irregularity (vertical profile shared by the rails, each with half a
   cross-level) and each rail's short-wave roughness (:mod:`~railwatch.physics.irregularity`);
2. the static deflection under a rolling wheel, which the wheel follows: deeper between sleepers
   than over one (:func:`~railwatch.physics.track.static_profile`), deeper over a soft or voided
   sleeper (each support's ballast stiffness varies log-normally, a few are voided), shallower
   on a bridge deck and a level crossing;
3. the features and the defects (:mod:`~railwatch.physics.features`), the defects only in the
   track's profile, not in its **clean twin**'s;
4. the wheel's size: a wheel of radius R cannot enter a dip shorter than its curvature allows,
   so near every item its centre runs along the upper envelope of circles rolled on the rail
   (a grey dilation); then the contact patch averages the profile over its length.

**A pass** (:func:`simulate_pass`) is the coach running over the track at a speed profile, in
either direction. Under each of its eight wheels the irregularity is sampled at the internal
rate ``fs_sim`` (each sample the mean over the distance the wheel rolled in it: no aliasing of
rail wavelengths shorter than a sample), the wheel's own out-of-roundness and flat added; the
coupled vehicle–track transfer functions (:mod:`~railwatch.physics.dynamics`) turn the eight
inputs into the six sensors' accelerations, the data acquisition's filters (AC coupling, the
anti-alias low-pass) are applied and the signal is sampled at the recording's rate ``fs``, and
each sensor's noise is added. The same pass over the clean twin, without the noise, is the
pass's clean twin: what the pass would have recorded without its defects and its sensor noise.
Every step is linear, so the twin and the pass differ by the defects' responses and the noise.

Parameters, their sources and the checks against published magnitudes: ``docs/physics.md``.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import grey_dilation, uniform_filter1d

from railwatch.errors import RailwatchError
from railwatch.physics.features import Inventory, Item, place_items
from railwatch.physics.irregularity import (
    IRREGULARITY_WAVELENGTHS_M,
    ROUGHNESS_DB,
    ROUGHNESS_WAVELENGTHS_M,
    irregularity_spectra,
    profile,
    roughness,
)
from railwatch.physics.track import TrackModel, static_profile
from railwatch.physics.vehicle import GROUPS, Vehicle

FloatArray = NDArray[np.float64]
log = logging.getLogger(__name__)

#: The rail's profile grid (m), and how far it runs beyond the track's ends (m): a pass's lead-in
#: and lead-out (4 s at up to 40 m/s) and the coach's length behind its sensors.
DX_M = 0.001
MARGIN_M = 200.0
#: Length (m) of the contact patch in the rolling direction (Hertz, 54.5 kN, wheel 0.46 m on a
#: rail head of 0.3 m radius: a semi-axis of about 6 mm).
PATCH_M = 0.012
#: Each item's neighbourhood (m) where the wheel's size is applied (:func:`wheel_path`).
WHEEL_SPAN_M = 0.05


@dataclass(frozen=True)
class Sensors:
    """The data acquisition: each group's noise (m/s² rms, white over the recorded band), the
    AC coupling's high-pass corner (Hz) and the anti-alias filter (flat to ``passband`` · fs,
    a cosine roll-off to fs / 2)."""

    noise_axle: float = 0.1
    noise_bogie: float = 0.02
    noise_body: float = 0.003
    highpass_hz: float = 0.5
    passband: float = 0.4

    def noise(self) -> FloatArray:
        by_group = {"axle": self.noise_axle, "bogie": self.noise_bogie, "body": self.noise_body}
        return np.array([by_group[g] for g in GROUPS])


@dataclass(frozen=True)
class World:
    """Everything a physics track and its passes are made of, with the defaults of
    ``docs/physics.md``; ``None`` irregularity or roughness leaves it out."""

    length_m: float = 5_000.0
    irregularity: str | None = "german-high"
    roughness: str | None = "average"
    #: Log-normal spread of each support's ballast and subgrade stiffness, and the share of
    #: voided sleepers (their support 5 times softer).
    support_spread: float = 0.2
    voided_share: float = 0.01
    inventory: Inventory = field(default_factory=Inventory)
    vehicle: Vehicle = field(default_factory=Vehicle)
    track: TrackModel = field(default_factory=TrackModel)
    sensors: Sensors = field(default_factory=Sensors)
    #: The coach's wheels: out-of-roundness per harmonic order 1-20 (rms amplitude of order n is
    #: ``oor_um / n`` µm) and a flat (depth mm, 0: none) on the leading wheelset's left wheel.
    oor_um: float = 10.0
    flat_mm: float = 0.0

    def check(self) -> None:
        """One-line errors for settings no world can have."""
        if not self.length_m >= 200.0:
            raise RailwatchError(f"a track must be at least 200 m long, got {self.length_m:g} m")
        if self.irregularity is not None:
            irregularity_spectra(self.irregularity)
        if self.roughness is not None and self.roughness not in ROUGHNESS_DB:
            raise RailwatchError(f"roughness {self.roughness!r}: use "
                                 f"{' or '.join(ROUGHNESS_DB)}")
        if self.support_spread < 0 or not 0 <= self.voided_share < 1:
            raise RailwatchError("support_spread must be >= 0 and voided_share in [0, 1)")
        if self.oor_um < 0 or self.flat_mm < 0:
            raise RailwatchError("the wheels' out-of-roundness and flat must be >= 0")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class PhysicsTrack:
    """A built track: its items and each rail's wheel path (the rails' height where a wheel
    centre rolls, m) with and without its defects, on the grid ``x0 + DX_M · i``."""

    world: World
    seed: int
    defects: list[Item]
    features: list[Item]
    x0: float
    path: FloatArray  # (2, n): rail 1, rail 2, with the defects
    clean: FloatArray  # (2, n): the clean twin
    base: FloatArray | None = None  # (2, n): the rails before any item (irregularity,
    # roughness, static deflection): what :func:`grown` rebuilds from

    def cumulative(self, clean: bool) -> FloatArray:
        """(2, n + 1): the running integral of the path (m²), for averaging over a stretch."""
        z = self.clean if clean else self.path
        out = np.zeros((2, z.shape[1] + 1))
        np.cumsum(z, axis=1, out=out[:, 1:])
        return out * DX_M


def build_track(world: World, seed: int, items: tuple[list[Item], list[Item]] | None = None
                ) -> PhysicsTrack:
    """The track of ``world`` drawn from ``seed`` (module docstring); ``items`` (defects,
    features) instead of drawing them."""
    world.check()
    rng = np.random.default_rng([seed, 300])
    defects, features = items if items is not None else place_items(
        world.length_m, world.inventory, np.random.default_rng([seed, 301]))
    x0 = -MARGIN_M
    span = world.length_m + 2 * MARGIN_M
    n = int(round(span / DX_M)) + 1
    z = np.zeros((2, n))
    if world.irregularity is not None:
        vertical, cross = irregularity_spectra(world.irregularity)
        _, v = profile(vertical, span, DX_M, np.random.default_rng([seed, 302]),
                       IRREGULARITY_WAVELENGTHS_M)
        z += v[:n]
        if cross is not None:
            _, c = profile(cross, span, DX_M, np.random.default_rng([seed, 303]),
                           IRREGULARITY_WAVELENGTHS_M)
            z[0] += c[:n] / 2
            z[1] -= c[:n] / 2
    if world.roughness is not None:
        for rail in range(2):
            _, r = profile(roughness(world.roughness), span, DX_M,
                           np.random.default_rng([seed, 304 + rail]), ROUGHNESS_WAVELENGTHS_M)
            z[rail] += r[:n]
    z -= _static_deflection(world, features, rng, x0, n)
    base = z.copy()
    every = [*features, *defects]
    radius = world.vehicle.wheel_radius_m
    clean = _with_items(z, features, every, x0, radius)
    path = _with_items(base.copy(), every, every, x0, radius)
    return PhysicsTrack(world=world, seed=seed, defects=defects, features=features, x0=x0,
                        path=path, clean=clean, base=base)


def _with_items(z: FloatArray, added: list[Item], rolled: list[Item], x0: float,
                radius: float, offset: int = 0) -> FloatArray:
    """The wheel path over rails ``z`` (changed in place; from grid point ``offset``): the
    ``added`` items' heights, the wheel's size over each ``rolled`` item in turn, then the
    contact patch."""
    for it in added:
        _add(z, it, x0, offset)
    for it in rolled:
        wheel_path(z, it, x0, radius, offset)
    return uniform_filter1d(z, max(1, int(round(PATCH_M / DX_M))), axis=1, mode="nearest")


def grown(track: PhysicsTrack, defects: list[Item]) -> PhysicsTrack:
    """The track with some of its defects changed (``defects``: items with the indices of
    ``track.defects``, a growing squat's deeper self): the wheel path rebuilt around each from
    the rails before any item, the rest of it, the features and the clean twin kept."""
    if track.base is None:
        raise ValueError("the track keeps no base profile to rebuild from")
    radius = track.world.vehicle.wheel_radius_m
    now = {it.index: it for it in track.defects}
    now.update({it.index: it for it in defects})
    ordered = [now[it.index] for it in track.defects]
    margin = 4 * WHEEL_SPAN_M + PATCH_M
    pad = int(np.ceil(margin / DX_M))
    path = track.path.copy()
    for it in defects:
        lo, hi = it.position_m - margin, it.end_m + margin
        while True:  # every item overlapping the stretch, whole, with a margin
            near = [o for o in [*track.features, *ordered]
                    if o.end_m >= lo and o.position_m <= hi]
            new_lo = min([lo, *(o.position_m - margin for o in near)])
            new_hi = max([hi, *(o.end_m + margin for o in near)])
            if (new_lo, new_hi) == (lo, hi):
                break
            lo, hi = new_lo, new_hi
        i0 = max(int(np.floor((lo - track.x0) / DX_M)) - pad, 0)
        i1 = min(int(np.ceil((hi - track.x0) / DX_M)) + pad, path.shape[1])
        seg = _with_items(track.base[:, i0:i1].copy(), near, near, track.x0, radius, i0)
        path[:, i0 + pad:i1 - pad] = seg[:, pad:seg.shape[1] - pad]
    return PhysicsTrack(world=track.world, seed=track.seed, defects=ordered,
                        features=track.features, x0=track.x0, path=path, clean=track.clean,
                        base=track.base)


def _rails(it: Item) -> list[int]:
    return [0, 1] if it.rail == 0 else [it.rail - 1]


def _add(z: FloatArray, it: Item, x0: float, offset: int = 0) -> None:
    """Add an item's height change to the rails it lies on (a step's far end stays shifted
    only over its relaxation length: beyond, the height change is 0); ``z`` starts at grid
    point ``offset`` of the track's grid from ``x0``."""
    i0 = int(np.floor((it.position_m - x0) / DX_M))
    i1 = int(np.ceil((it.end_m - x0) / DX_M)) + 1
    s = x0 + DX_M * np.arange(i0, i1, dtype=float) - it.position_m
    dz = it.height(s)
    for r in _rails(it):
        z[r, i0 - offset:i1 - offset] += dz


def wheel_path(z: FloatArray, it: Item, x0: float, radius: float, offset: int = 0) -> None:
    """Where a wheel of ``radius`` rolls over the item: the upper envelope of the circles on the
    rail, ``max_s z(x + s) + √(R² − s²) − R`` over |s| ≤ :data:`WHEEL_SPAN_M` (in place, over
    the item and that span either side; ``z`` starts at grid point ``offset``)."""
    half = int(round(WHEEL_SPAN_M / DX_M))
    s = DX_M * np.arange(-half, half + 1)
    circle = np.sqrt(radius**2 - s**2) - radius
    i0 = max(int(np.floor((it.position_m - x0) / DX_M)) - 2 * half - offset, 0)
    i1 = min(int(np.ceil((it.end_m - x0) / DX_M)) + 2 * half + 1 - offset, z.shape[1])
    for r in _rails(it):
        seg = z[r, i0:i1]
        out = grey_dilation(seg, structure=circle, size=len(circle), mode="nearest")
        z[r, i0 + half:i1 - half] = out[half:len(seg) - half]


def _static_deflection(world: World, features: list[Item], rng: np.random.Generator,
                       x0: float, n: int) -> FloatArray:
    """(2, n): the static deflection (m, downwards) under a wheel at every grid point of each
    rail: the bay's profile between sleepers, scaled by the local support's stiffness."""
    track = world.track
    a = track.spacing_m
    n_sleepers = int(np.ceil((n * DX_M) / a)) + 2
    x_sleeper = x0 + a * np.arange(n_sleepers)
    scale = np.exp(rng.normal(0.0, world.support_spread, (2, n_sleepers)))
    scale[rng.random((2, n_sleepers)) < world.voided_share] = 0.2
    for it in features:
        span = it.support_scale
        if span is not None:
            on = (x_sleeper >= span[0]) & (x_sleeper < span[1])
            scale[:, on] *= span[2]
    # A wheel's deflection feels the supports within a few sleepers: weigh them by the beam
    # on elastic foundation's influence line, e^(−βx)(cos βx + sin βx) (Hetényi 1946).
    k_seat = track.support_stiffness()
    beta = (k_seat / a / (4 * track.rail_E_pa * track.rail_I_m4)) ** 0.25
    offsets = a * np.arange(-6, 7)
    w = np.exp(-beta * np.abs(offsets)) * (np.cos(beta * np.abs(offsets))
                                            + np.sin(beta * np.abs(offsets)))
    w = np.clip(w, 0.0, None)
    w /= w.sum()
    stiff = np.stack([np.convolve(track.support_stiffness(s), w, mode="same") for s in scale])
    gain = (stiff / k_seat) ** -0.75
    bay = static_profile(track, world.vehicle.static_wheel_load_n)  # (per,) from a sleeper
    x = x0 + DX_M * np.arange(n)
    u = (x - x0) / a
    k = np.floor(u).astype(np.int64)
    frac = u - k
    per = len(bay)
    pos = frac * per
    j = np.floor(pos).astype(np.int64)
    t = pos - j
    in_bay = bay[j % per] * (1 - t) + bay[(j + 1) % per] * t
    out = np.empty((2, n))
    for r in range(2):
        g = gain[r, k] * (1 - frac) + gain[r, np.minimum(k + 1, n_sleepers - 1)] * frac
        out[r] = in_bay * g
    return out - out.mean(axis=1, keepdims=True)
