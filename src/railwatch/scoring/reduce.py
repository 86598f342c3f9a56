"""From per-channel scores to point and instance scores, and to a localisation.

Every detector gives ``channel`` scores (N, T, C); the default reductions take the maximum over
channels (``point``, (N, T)) and then over time (``instance``, (N,)); localisation is the argmax
of ``point`` and the argmax of ``channel`` at that time. Arrays in, arrays out: nothing here knows
a detector (``railwatch.detectors`` calls it), nor torch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float32]


@dataclass(frozen=True)
class Localization:
    """The most anomalous time step and channel of each window."""

    time_index: NDArray[np.int64]  # (N,)
    time_s: NDArray[np.float64]  # (N,) seconds from the window start
    channel: NDArray[np.int64]  # (N,)


def reduce_point_max(channel: FloatArray) -> FloatArray:
    """Default point reduction: ``point = max over channels of channel`` (N, T, C) -> (N, T)."""
    return channel.max(axis=2)


def reduce_instance_max(point: FloatArray) -> FloatArray:
    """Default instance reduction: ``instance = max over time of point`` (N, T) -> (N,)."""
    return point.max(axis=1)


def localize(point: NDArray[np.floating], channel: NDArray[np.floating], fs: float
             ) -> Localization:
    """Time index = argmax of ``point`` (N, T); channel = argmax of ``channel`` (N, T, C) at that
    time; seconds at ``fs`` Hz.

    >>> ch = np.zeros((1, 4, 2)); ch[0, 2, 1] = 5.0
    >>> loc = localize(ch.max(axis=2), ch, fs=2.0)
    >>> int(loc.time_index[0]), float(loc.time_s[0]), int(loc.channel[0])
    (2, 1.0, 1)
    """
    t = point.argmax(axis=1)
    c = channel[np.arange(len(t)), t].argmax(axis=1)
    return Localization(time_index=t.astype(np.int64), time_s=t / fs, channel=c.astype(np.int64))
