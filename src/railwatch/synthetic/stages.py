"""The eight stages of the incremental benchmark: parameter ranges, one short function per stage,
and the sampling of every per-channel random variable.

Source: the paper's section "Incremental synthetic data benchmark" as settled by
``docs/benchmark.md``, "Stages" (spec version :data:`SPEC_VERSION`). Each stage builds on the
previous one.

>>> stage(7).n_channels, stage(7).n_random_variables
(6, 84)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

SPEC_VERSION = "1.0"

Range = tuple[float, float]


@dataclass(frozen=True)
class GroupRanges:
    """Uniform ranges U[a, b] of one sensor group (the spec's "Ranges" table)."""

    f: Range
    amp: Range
    alpha_hf: Range = (0.0, 0.0)
    f_hf: Range = (0.0, 0.0)
    imp_period: Range = (0.0, 0.0)
    beta: Range = (0.0, 0.0)
    # Shared by every group.
    sigma: Range = (0.1, 0.5)
    t_change: Range = (0.4, 1.6)
    k_f: Range = (0.5, 1.5)
    k_a: Range = (0.5, 1.5)
    phi: Range = (0.0, 2 * np.pi)
    d_sigma: Range = (0.1, 0.5)
    t_noisechange: Range = (0.4, 1.6)
    t_hf: Range = (0.4, 1.6)
    dt_hf: Range = (0.05, 0.2)
    psi: Range = (0.0, 2 * np.pi)
    omega: Range = (0.01, 0.1)


GROUPS: dict[str, GroupRanges] = {
    # Stages 1-4: one set of ranges for every channel.
    "generic": GroupRanges(f=(1.0, 15.0), amp=(0.5, 2.0)),
    "axle": GroupRanges(
        f=(1.0, 25.0), amp=(0.5, 2.0), alpha_hf=(0.5, 2.0), f_hf=(25.0, 50.0),
        imp_period=(0.1, 0.3), beta=(0.5, 2.0),
    ),
    "bogie": GroupRanges(
        f=(1.0, 15.0), amp=(0.3, 1.5), alpha_hf=(0.3, 1.5), f_hf=(15.0, 40.0),
        imp_period=(0.15, 0.3), beta=(0.3, 1.5),
    ),
    "body": GroupRanges(
        f=(1.0, 5.0), amp=(0.2, 1.0), alpha_hf=(0.2, 1.0), f_hf=(5.0, 30.0),
        imp_period=(0.2, 0.5), beta=(0.2, 1.0),
    ),
}

#: Stages 6-8: the anomalous channel is drawn from these kind-specific odds (spikes favour the
#: axle, local deviations the body).
P_SPIKE = (0.25, 0.25, 0.15, 0.15, 0.10, 0.10)
P_LOCAL = (0.10, 0.10, 0.15, 0.15, 0.25, 0.25)

#: Per-channel random variables of each component, in their draw order within their seed stream.
BASE_VARS = ("f", "amp", "sigma")
PHASE_VARS = ("phi",)
SPEED_VARS = ("t_change", "k_f", "k_a")
NOISE_CHANGE_VARS = ("d_sigma", "t_noisechange")
BURST_VARS = ("t_hf", "dt_hf", "psi", "alpha_hf", "f_hf")
IMPULSE_VARS = ("omega", "imp_period", "beta")


@dataclass(frozen=True)
class StageConfig:
    """What a stage contains. Each flag switches one component on."""

    number: int
    name: str
    groups: tuple[str, ...] = ("generic",)
    speed_change: bool = False
    phase: bool = False
    noise_change: bool = False
    heterogeneous_odds: bool = False
    bursts: bool = False
    impulses: bool = False
    channel_names: tuple[str, ...] = field(default=("ch1",))

    @property
    def n_channels(self) -> int:
        return len(self.groups)

    @property
    def variables(self) -> tuple[str, ...]:
        """Names of the per-channel random variables of this stage, in stream order."""
        names: tuple[str, ...] = BASE_VARS
        if self.phase:
            names += PHASE_VARS
        if self.speed_change:
            names += SPEED_VARS
        if self.noise_change:
            names += NOISE_CHANGE_VARS
        if self.bursts:
            names += BURST_VARS
        if self.impulses:
            names += IMPULSE_VARS
        return names

    @property
    def n_random_variables(self) -> int:
        """The count in the paper's Figure 1 titles: per-channel variables × channels."""
        return len(self.variables) * self.n_channels

    def channel_odds(self, kind: int) -> NDArray[np.float64]:
        """Probability of each channel carrying an anomaly of ``kind`` (1 spike, 2 local)."""
        if self.heterogeneous_odds:
            return np.array(P_SPIKE if kind == 1 else P_LOCAL)
        return np.full(self.n_channels, 1.0 / self.n_channels)


SIX_CHANNELS = ("axle", "axle", "bogie", "bogie", "body", "body")
SIX_NAMES = ("axle1", "axle2", "bogie1", "bogie2", "body1", "body2")


def stage_1() -> StageConfig:
    return StageConfig(1, "Baseline")


def stage_2() -> StageConfig:
    return replace(stage_1(), number=2, name="Speed variation", speed_change=True)


def stage_3() -> StageConfig:
    return replace(
        stage_2(), number=3, name="2 channels", groups=("generic",) * 2,
        channel_names=("ch1", "ch2"), phase=True,
    )


def stage_4() -> StageConfig:
    return replace(stage_3(), number=4, name="Larger noise", noise_change=True)


def stage_5() -> StageConfig:
    return replace(
        stage_4(), number=5, name="6 channels", groups=SIX_CHANNELS, channel_names=SIX_NAMES
    )


def stage_6() -> StageConfig:
    return replace(stage_5(), number=6, name="Heterogeneous anomaly odds", heterogeneous_odds=True)


def stage_7() -> StageConfig:
    return replace(stage_6(), number=7, name="HF local noise", bursts=True)


def stage_8() -> StageConfig:
    return replace(stage_7(), number=8, name="Periodic impulses", impulses=True)


STAGES: dict[int, Callable[[], StageConfig]] = {
    1: stage_1, 2: stage_2, 3: stage_3, 4: stage_4,
    5: stage_5, 6: stage_6, 7: stage_7, 8: stage_8,
}


def stage(number: int) -> StageConfig:
    """The configuration of stage ``number`` (1-8)."""
    if number not in STAGES:
        raise ValueError(f"stage must be an integer from 1 to 8, got {number!r}")
    return STAGES[number]()


def draw_uniform(
    rng: np.random.Generator, names: tuple[str, ...], groups: tuple[str, ...], n: int
) -> dict[str, NDArray[np.float64]]:
    """Draw each named variable U[a, b] per instance and channel, a, b from each channel's group.

    Returns arrays of shape (n, C), drawn in the order of ``names`` so that a stream's draws do not
    depend on which other components a stage has.
    """
    out = {}
    for name in names:
        lo = np.array([getattr(GROUPS[g], name)[0] for g in groups])
        hi = np.array([getattr(GROUPS[g], name)[1] for g in groups])
        out[name] = rng.uniform(lo, hi, size=(n, len(groups)))
    return out
