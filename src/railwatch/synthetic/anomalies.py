"""Anomaly injection: which instances, which kind, which channel, where and how large.

All anomaly variables are drawn in seconds from one seed stream, before any sampling grid is
known, so that the same seed places the same anomalies at any ``fs`` (field-rate mode).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from railwatch.synthetic.components import span_mask
from railwatch.synthetic.stages import StageConfig
from railwatch.windows import LOCAL, NORMAL, SPIKE

ANOMALY_RATE = 0.10
#: The benchmark's reference rate: a spike lasts one sample of it (0.01 s) at any fs.
REFERENCE_FS = 100.0
SPIKE_OFFSET = (2.0, 4.0)
LOCAL_OFFSET = (1.0, 2.0)
LOCAL_DURATION = (0.05, 0.2)


def round_half_up(x: float) -> int:
    """``round`` as the spec means it (0.5 goes up), not Python's banker's rounding."""
    return int(np.floor(x + 0.5))


@dataclass(frozen=True)
class Anomalies:
    """Labels of n instances. Times in seconds; ``channel`` and the spans are −1/0 when normal."""

    kind: NDArray[np.int8]  # (n,) 0 normal, 1 spike, 2 local deviation
    channel: NDArray[np.int16]  # (n,) anomalous channel index or -1
    start: NDArray[np.float64]  # (n,) s, first instant of the offset
    duration: NDArray[np.float64]  # (n,) s
    offset: NDArray[np.float64]  # (n,) signed offset added to the signal

    @property
    def y(self) -> NDArray[np.int8]:
        return (self.kind != NORMAL).astype(np.int8)

    def mask(self, t: NDArray[np.float64], n_channels: int) -> NDArray[np.bool_]:
        """(n, T, C) boolean: true exactly where the offset is added."""
        in_span = span_mask(t, self.start, self.duration) & (self.kind != NORMAL)[:, None]
        on_channel = np.arange(n_channels)[None, :] == self.channel[:, None]
        return in_span[:, :, None] & on_channel[:, None, :]


def sample_anomalies(
    rng: np.random.Generator,
    cfg: StageConfig,
    n: int,
    duration: float,
    exact_rate: bool = True,
) -> Anomalies:
    """Draw the anomaly labels of ``n`` instances from the anomaly stream ``rng``.

    Exactly ``round(0.10 n)`` anomalous instances (``round(0.05 n)`` spikes, the rest local
    deviations) at random positions, or Bernoulli(0.10) per instance with the kind 50/50 when
    ``exact_rate`` is false. The channel is drawn from the stage's kind-specific odds.
    """
    kind = np.zeros(n, dtype=np.int8)
    if exact_rate:
        n_anomalous = round_half_up(ANOMALY_RATE * n)
        n_spikes = min(round_half_up(ANOMALY_RATE / 2 * n), n_anomalous)
        order = rng.permutation(n)
        kind[order[:n_spikes]] = SPIKE
        kind[order[n_spikes:n_anomalous]] = LOCAL
    else:
        anomalous = rng.random(n) < ANOMALY_RATE
        kind[anomalous] = np.where(rng.random(n) < 0.5, SPIKE, LOCAL)[anomalous]

    # Every variable is drawn for every instance in a fixed order; each instance uses its own.
    u_channel = rng.random(n)
    t_spike = rng.uniform(0.0, duration, n)
    local_dt = rng.uniform(*LOCAL_DURATION, n)
    local_start = rng.uniform(0.0, 1.0, n) * (duration - local_dt)  # U[0, duration − Δt]
    spike_size = rng.uniform(*SPIKE_OFFSET, n)
    local_size = rng.uniform(*LOCAL_OFFSET, n)
    sign = np.where(rng.random(n) < 0.5, -1.0, 1.0)

    channel = np.full(n, -1, dtype=np.int16)
    for k in (SPIKE, LOCAL):
        cdf = np.cumsum(cfg.channel_odds(k))
        pick = np.minimum(np.searchsorted(cdf / cdf[-1], u_channel, side="right"), len(cdf) - 1)
        channel = np.where(kind == k, pick, channel).astype(np.int16)

    is_spike, is_local = kind == SPIKE, kind == LOCAL
    # A spike is one sample of the 100 Hz reference grid: index floor(t_spike · 100).
    spike_start = np.floor(t_spike * REFERENCE_FS) / REFERENCE_FS
    start = np.select([is_spike, is_local], [spike_start, local_start], 0.0)
    dur = np.select([is_spike, is_local], [np.full(n, 1.0 / REFERENCE_FS), local_dt], 0.0)
    offset = sign * np.select([is_spike, is_local], [spike_size, local_size], 0.0)
    return Anomalies(kind=kind, channel=channel, start=start, duration=dur, offset=offset)
