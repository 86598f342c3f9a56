"""What is on the track: defects and features as rail geometry, and where they are.

Every item changes the height of one rail or both (m, upwards positive) over a stretch of
track, as a function of the distance ``s`` from where it starts; the vehicle meets each the same
way on every pass (a pass the other way meets it mirrored). **Defects** are what an inspector
should see; **features** answer on every pass and are not defects (turnouts, bridge transitions,
level crossings). Shapes, sizes and their sources: ``docs/physics.md``.

============== ============================================================================
squat          a dip 2–10 cm long, 0.1–1.5 mm deep (the deeper, the longer), flat-bottomed
               with cosine edges
joint          a dipped (insulated or fishplated) joint: a V-shaped dip of 0.5–3 mm over
               0.3–1 m, a gap of 5–10 mm at its bottom and a step of up to 0.3 mm across it
weld           a dip of 0.1–0.5 mm over 0.6–1.2 m with a crown at its centre
step           a broken rail: a gap of 5–30 mm and the far end 0.5–3 mm higher or lower,
               relaxing over 3 m
corrugation    short-pitch corrugation: a sine of 30–80 mm wavelength, 0.02–0.2 mm peak to
               trough, over a patch of 1–5 m (tapered ends)
switch         a turnout's switch toe: a dip of 0.3–1 mm over 0.3–0.6 m on both rails
crossing       a turnout's crossing nose, 20–30 m after its switch: the wheel drops 1–2.5 mm
               over 0.3–0.5 m and climbs back on the nose, on one rail
transition     a bridge's end: the track's support 3–5 times stiffer on the deck, and a
               settlement dip of 2–8 mm over 5–15 m on the approach (both rails)
level-crossing a dip of 1–3 mm over 2–5 m, both rails, and a support 2 times stiffer over it
============== ============================================================================
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railwatch.errors import RailwatchError

FloatArray = NDArray[np.float64]

DEFECT_KINDS = ("squat", "joint", "weld", "step", "corrugation")
FEATURE_KINDS = ("switch", "crossing", "transition", "level-crossing")

#: Columns of a track's items table (track.defects.csv, track.features.csv): ``rail`` is 1 (the
#: left rail looking along increasing position), 2 (the right one) or 0 (both); ``depth_mm`` the
#: item's size (a dip's depth, a step's height, a corrugation's peak-to-trough), signed where
#: it can be a hump or a step up.
ITEM_FIELDS = ("defect", "kind", "position_m", "length_m", "depth_mm", "rail", "detail")


@dataclass(frozen=True)
class Item:
    """A defect or feature: where it starts and ends along the track, and its shape."""

    index: int
    kind: str
    position_m: float  # where it starts (m)
    length_m: float
    depth_mm: float  # signed size (see ITEM_FIELDS)
    rail: int  # 1, 2 or 0: both
    params: tuple[tuple[str, float], ...] = ()  # shape parameters beyond length and depth

    @property
    def end_m(self) -> float:
        return self.position_m + self.length_m

    def param(self, name: str) -> float:
        return dict(self.params)[name]

    def row(self) -> dict[str, Any]:
        d = asdict(self)
        detail = " ".join(f"{k}={v:.4g}" for k, v in self.params)
        return {"defect": d["index"], "kind": self.kind, "position_m": round(self.position_m, 4),
                "length_m": round(self.length_m, 4), "depth_mm": round(self.depth_mm, 4),
                "rail": self.rail, "detail": detail}

    def height(self, s: FloatArray) -> FloatArray:
        """The rail's height change (m) at distances ``s`` (m) from :attr:`position_m` (0
        outside ``[0, length_m]``, except a step, whose far end stays where it relaxed to)."""
        return SHAPES[self.kind](self, np.asarray(s, dtype=float))

    @property
    def support_scale(self) -> tuple[float, float, float] | None:
        """(start m, end m, factor) where the item changes the track's support stiffness."""
        if self.kind == "transition":
            deck = self.param("deck_m")
            start = self.end_m if self.param("side") > 0 else self.position_m - deck
            return start, start + deck, self.param("stiffness")
        if self.kind == "level-crossing":
            return self.position_m, self.end_m, 2.0
        return None


def _tukey(u: FloatArray, taper: float) -> FloatArray:
    """1 on the middle of [0, 1], cosine tapers of width ``taper`` at each end, 0 outside."""
    out = np.where((u >= 0) & (u <= 1), 1.0, 0.0)
    for edge in (u, 1 - u):
        ramp = (edge >= 0) & (edge < taper)
        out[ramp] *= 0.5 * (1 - np.cos(np.pi * edge[ramp] / taper))
    return out


def _squat(it: Item, s: FloatArray) -> FloatArray:
    return -it.depth_mm * 1e-3 * _tukey(s / it.length_m, 0.3)


def _v_dip(s: FloatArray, length: float) -> FloatArray:
    """A V of unit depth over ``length``: 0 at both ends, 1 in the middle."""
    u = s / length
    return np.clip(1 - np.abs(2 * u - 1), 0.0, None) * ((u >= 0) & (u <= 1))


def _joint(it: Item, s: FloatArray) -> FloatArray:
    gap = it.param("gap_mm") * 1e-3
    mid = it.length_m / 2
    z = -it.depth_mm * 1e-3 * _v_dip(s, it.length_m)
    far_end = (s > mid) & (s <= it.length_m)
    z -= it.param("step_mm") * 1e-3 * far_end * (1 - _v_dip(s, it.length_m))
    z[np.abs(s - mid) < gap / 2] -= 0.02  # the gap: 20 mm deep, the wheel bridges it
    return z


def _weld(it: Item, s: FloatArray) -> FloatArray:
    u = s / it.length_m
    inside = (u >= 0) & (u <= 1)
    z = -it.depth_mm * 1e-3 * 0.5 * (1 - np.cos(2 * np.pi * u)) * inside
    crown = it.param("crown_m")
    c = (s - it.length_m / 2) / crown
    z += it.param("crown_mm") * 1e-3 * 0.5 * (1 + np.cos(np.pi * np.clip(c, -1, 1))) \
        * (np.abs(c) < 1)
    return z


def _step(it: Item, s: FloatArray) -> FloatArray:
    gap = it.param("gap_mm") * 1e-3
    relax = it.length_m - gap
    after = s - gap
    z = it.depth_mm * 1e-3 * np.where(after < 0, 0.0,
                                      0.5 * (1 + np.cos(np.pi * np.clip(after / relax, 0, 1))))
    z = np.where(after >= relax, 0.0, z)
    z[(s >= 0) & (s < gap)] -= 0.03  # the gap between the broken ends
    return z


def _corrugation(it: Item, s: FloatArray) -> FloatArray:
    envelope = _tukey(s / it.length_m, min(0.5, 0.3 / it.length_m))
    return 0.5 * it.depth_mm * 1e-3 * np.sin(2 * np.pi * s / it.param("wavelength_m")) * envelope


def _switch(it: Item, s: FloatArray) -> FloatArray:
    return -it.depth_mm * 1e-3 * 0.5 * (1 - np.cos(2 * np.pi * s / it.length_m)) \
        * ((s >= 0) & (s <= it.length_m))


def _crossing(it: Item, s: FloatArray) -> FloatArray:
    # The wheel runs down the wing rail to the nose (80 % of the length) and climbs the nose.
    nose = 0.8 * it.length_m
    u = np.where(s < nose, s / nose, 1 - (s - nose) / (it.length_m - nose))
    return -it.depth_mm * 1e-3 * np.clip(u, 0, 1) * ((s >= 0) & (s <= it.length_m))


def _transition(it: Item, s: FloatArray) -> FloatArray:
    # The settlement dip lies on the approach, deepest next to the deck's end.
    u = s / it.length_m if it.param("side") > 0 else 1 - s / it.length_m
    return -it.depth_mm * 1e-3 * 0.5 * (1 - np.cos(np.pi * np.clip(u, 0, 1))) \
        * ((s >= 0) & (s <= it.length_m))


SHAPES = {"squat": _squat, "joint": _joint, "weld": _weld, "step": _step,
          "corrugation": _corrugation, "switch": _switch, "crossing": _crossing,
          "transition": _transition, "level-crossing": _switch}


@dataclass(frozen=True)
class Inventory:
    """How many items of each kind a track has per km, and the size ranges they are drawn
    from (``docs/physics.md`` gives each range's source). Depths of squats are drawn
    log-uniformly, so that probability-of-detection curves have points at every size."""

    squats_per_km: float = 2.4
    joints_per_km: float = 1.2
    welds_per_km: float = 1.4
    steps_per_km: float = 0.6
    corrugations_per_km: float = 0.4
    turnouts_per_km: float = 0.4
    bridges_per_km: float = 0.2
    level_crossings_per_km: float = 0.2
    squat_depth_mm: tuple[float, float] = (0.1, 1.5)
    squat_length_m: tuple[float, float] = (0.02, 0.10)
    joint_depth_mm: tuple[float, float] = (0.5, 3.0)
    weld_depth_mm: tuple[float, float] = (0.1, 0.5)
    step_height_mm: tuple[float, float] = (0.5, 3.0)
    corrugation_depth_mm: tuple[float, float] = (0.02, 0.2)
    #: Items at least this far apart (m), so that each place on the map is one item.
    min_gap_m: float = 25.0


def _count(per_km: float, km: float) -> int:
    """Round(per_km · km), at least one where the rate is positive (a test track without any
    joint would not test joints)."""
    return max(1, int(round(per_km * km))) if per_km > 0 else 0


def place_items(length_m: float, inventory: Inventory,
                rng: np.random.Generator) -> tuple[list[Item], list[Item]]:
    """Draw a track's defects and features (each ``min_gap_m`` from the others and from the
    track's ends): returns (defects, features), each sorted by position."""
    km = length_m / 1000.0
    gap = inventory.min_gap_m
    taken: list[tuple[float, float]] = []

    def free(start: float, end: float) -> bool:
        return start >= gap and end <= length_m - gap and all(
            end + gap <= a or start >= b + gap for a, b in taken)

    def put(span: float, tries: int = 2000) -> float:
        for _ in range(tries):
            start = float(rng.uniform(gap, max(gap, length_m - gap - span)))
            if free(start, start + span):
                taken.append((start, start + span))
                return start
        raise RailwatchError(f"the items do not fit on {length_m:g} m of track {gap:g} m apart: "
                             "give a longer track or fewer items per km")

    features: list[Item] = []
    for _ in range(_count(inventory.bridges_per_km, km)):
        deck = float(rng.uniform(20.0, 80.0))
        app = [float(rng.uniform(5.0, 15.0)) for _ in range(2)]
        start = put(app[0] + deck + app[1])
        stiff = float(rng.uniform(3.0, 5.0))
        for side, pos, length in ((1, start, app[0]), (-1, start + app[0] + deck, app[1])):
            features.append(Item(0, "transition", pos, length, float(rng.uniform(2.0, 8.0)), 0,
                                 (("side", float(side)), ("deck_m", deck),
                                  ("stiffness", stiff))))
    for _ in range(_count(inventory.turnouts_per_km, km)):
        lead = float(rng.uniform(20.0, 30.0))
        sw_len, cr_len = float(rng.uniform(0.3, 0.6)), float(rng.uniform(0.3, 0.5))
        # The crossing nose lies ``lead`` beyond the switch toe, whichever end a train
        # running up the track meets first.
        start = put(lead + max(sw_len, cr_len))
        switch, nose = (start, start + lead) if rng.random() < 0.5 else (start + lead, start)
        features.append(Item(0, "switch", switch, sw_len, float(rng.uniform(0.3, 1.0)), 0))
        features.append(Item(0, "crossing", nose, cr_len, float(rng.uniform(1.0, 2.5)),
                             int(rng.integers(1, 3))))
    for _ in range(_count(inventory.level_crossings_per_km, km)):
        length = float(rng.uniform(2.0, 5.0))
        features.append(Item(0, "level-crossing", put(length), length,
                             float(rng.uniform(1.0, 3.0)), 0))

    defects: list[Item] = []
    for _ in range(_count(inventory.squats_per_km, km)):
        # A squat grows in length and depth together: its length rises with the depth's
        # place in the log-uniform range, give or take a tenth of the length range.
        lo, hi = inventory.squat_depth_mm
        u = float(rng.uniform(0.0, 1.0))
        depth = float(np.exp(np.log(lo) + u * (np.log(hi) - np.log(lo))))
        short, long = inventory.squat_length_m
        length = float(np.clip(short + (long - short) * (u + rng.normal(0.0, 0.1)), short, long))
        defects.append(Item(0, "squat", put(length), length, depth, int(rng.integers(1, 3))))
    for _ in range(_count(inventory.joints_per_km, km)):
        length = float(rng.uniform(0.3, 1.0))
        defects.append(Item(0, "joint", put(length), length,
                            float(rng.uniform(*inventory.joint_depth_mm)),
                            int(rng.integers(1, 3)),
                            (("gap_mm", float(rng.uniform(5.0, 10.0))),
                             ("step_mm", float(rng.uniform(-0.3, 0.3))))))
    for _ in range(_count(inventory.welds_per_km, km)):
        length = float(rng.uniform(0.6, 1.2))
        depth = float(rng.uniform(*inventory.weld_depth_mm))
        defects.append(Item(0, "weld", put(length), length, depth, int(rng.integers(1, 3)),
                            (("crown_mm", float(rng.uniform(0.0, 0.5)) * depth),
                             ("crown_m", float(rng.uniform(0.05, 0.15))))))
    for _ in range(_count(inventory.steps_per_km, km)):
        gap_mm = float(rng.uniform(5.0, 30.0))
        length = gap_mm * 1e-3 + 3.0
        height = float(rng.uniform(*inventory.step_height_mm)) * float(rng.choice([-1.0, 1.0]))
        defects.append(Item(0, "step", put(length), length, height, int(rng.integers(1, 3)),
                            (("gap_mm", gap_mm),)))
    for _ in range(_count(inventory.corrugations_per_km, km)):
        length = float(rng.uniform(1.0, 5.0))
        defects.append(Item(0, "corrugation", put(length), length,
                            float(rng.uniform(*inventory.corrugation_depth_mm)),
                            int(rng.integers(1, 3)),
                            (("wavelength_m", float(rng.uniform(0.03, 0.08))),)))

    def numbered(items: list[Item]) -> list[Item]:
        items = sorted(items, key=lambda it: it.position_m)
        return [Item(i, it.kind, it.position_m, it.length_m, it.depth_mm, it.rail, it.params)
                for i, it in enumerate(items)]

    return numbered(defects), numbered(features)
