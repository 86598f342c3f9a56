"""The rails' height under a wheelset, measured by its two axle boxes.

A weld is a smooth dip of 0.1-0.5 mm over about a metre; its axle-box answer lies in the same
band as the rail's own texture (its supports, roughness and irregularity), so an event detector
that whitens a window in time loses most of it (``docs/notes/2026-12-03-welds-against-the-
bound.md``). The rail's height itself holds it: the whitened matched filter of a weld's shape on
the true height (:mod:`railwatch.physics.bound`) finds 95 % of the physics world's welds of 0.3
mm or more. This module measures that height; :mod:`railwatch.detection.welds` tests it.

1. **The wheelset's response** (:func:`identify`, at ``train``). Below its first resonance a
   wheelset follows the rail; around it (P2, the wheelset bouncing on the track, 30-90 Hz) and
   above, the axle box sees the rail through the vehicle's response ``G(f)``. Two axle boxes of
   one wheelset split it into bounce (their sum, both rails' mean) and roll (their difference).
   ``G`` is found from the recordings themselves, without labels: a block of a few seconds at a
   steady speed ``v`` has the spectrum ``|G(f)|² S(f/v) / v``, where ``S`` is the rails' height
   spectrum in space (cycles per m), the same at every speed. Over many blocks at different
   speeds, ``log P = 2 log|G(f)| + log S(f/v) − log v`` is linear in the two unknown curves
   (each on a log grid), and a sparse least-squares fit (``scipy.sparse.linalg.lsqr``, smoothed
   by second differences) gives both, up to the gauge ``|G| = 1`` below 10 Hz, where the wheel
   follows the rail. It needs speeds that differ (at least :data:`MIN_SPEED_RATIO` apart).
2. **Its phase**: the minimum phase of that magnitude (the response of a mechanical system to
   a displacement at its base has no zeros to the right; on the physics world the minimum phase
   is within 10° of the true one up to 100 Hz, and above it differs by a delay of about 0.3 ms,
   a few mm of track, which a weld's test does not feel).
3. **The height** (:func:`rail_heights`): both axle boxes' accelerations divided by
   ``−ω² G`` between :data:`F_LOW_HZ` and :data:`ANTI_ALIAS_SHARE` of the rate, then laid on a
   grid of distance travelled (:func:`on_distance`).

Measured on the physics world (``docs/physics.md``, "Welds: the rails' height"): the identified
``|G|`` within 5 % of the model's from 2 to 700 Hz, its P2 peak included.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import sparse
from scipy.signal import get_window
from scipy.sparse.linalg import lsqr

from railwatch.errors import RailwatchError

FloatArray = NDArray[np.float64]

#: Identification: blocks of this long (s) whose speed varies by less than :data:`STEADY`.
BLOCK_S = 2.0
STEADY = 1.05
#: The slowest block used (m/s): a coach standing at a platform measures no track.
MIN_BLOCK_SPEED = 2.0
#: The band fitted and deconvolved (Hz): from here to this share of the rate (an anti-alias
#: filter is flat to about 0.4-0.45 of the rate).
F_LOW_HZ = 2.0
ANTI_ALIAS_SHARE = 0.4
#: The gauge: the wheel follows the rail below this frequency (Hz).
GAUGE_HZ = 10.0
#: Points per octave of the fitted curves: the response's (its P2 peak is a few Hz wide) and
#: the rails' spectrum's.
PER_OCTAVE_RESPONSE = 24
PER_OCTAVE_TRACK = 12
#: The fastest block over the slowest that identification needs.
MIN_SPEED_RATIO = 1.3
#: Blocks that identification needs (2 s each: about 3 minutes of recording).
MIN_BLOCKS = 60
#: The grid of the rails' height along the track (m): a weld's crown is 5-15 cm long.
DX_M = 0.01


@dataclass(frozen=True)
class AxleResponse:
    """A wheelset's identified response to the rails' height (:func:`identify`): on the grid
    ``freq_hz``, the natural log of the gain of bounce (the two axle boxes' sum over twice the
    rails' mean height) and of roll (their difference), displacement over displacement, 1 below
    :data:`GAUGE_HZ`; the recordings' rate and the speeds it was identified over."""

    fs: float
    freq_hz: tuple[float, ...]
    bounce: tuple[float, ...]
    roll: tuple[float, ...]
    speed_ms: tuple[float, float]

    @property
    def p2_hz(self) -> float:
        """The frequency of the bounce's highest gain between 20 and 200 Hz: P2, the wheelset
        bouncing on the track."""
        f = np.asarray(self.freq_hz)
        band = (f >= 20.0) & (f <= 200.0)
        return float(f[band][np.argmax(np.asarray(self.bounce)[band])])

    def transfer(self, n_fft: int) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
        """Bounce's and roll's minimum-phase response on ``np.fft.rfftfreq(n_fft, 1 / fs)``."""
        f = np.fft.rfftfreq(n_fft, 1 / self.fs)
        lf = np.log(np.maximum(f, 1e-6))
        grid = np.log(np.asarray(self.freq_hz))
        return tuple(minimum_phase(np.exp(np.interp(lf, grid, np.asarray(g))))  # type: ignore
                     for g in (self.bounce, self.roll))

    def to_dict(self) -> dict[str, Any]:
        return {"fs": self.fs, "freq_hz": [round(f, 4) for f in self.freq_hz],
                "bounce": [round(g, 5) for g in self.bounce],
                "roll": [round(g, 5) for g in self.roll], "speed_ms": list(self.speed_ms),
                "p2_hz": round(self.p2_hz, 2)}

    @classmethod
    def from_dict(cls, values: Any) -> AxleResponse:
        """Read back :meth:`to_dict`; a ValueError names what is wrong."""
        try:
            out = cls(float(values["fs"]), tuple(float(f) for f in values["freq_hz"]),
                      tuple(float(g) for g in values["bounce"]),
                      tuple(float(g) for g in values["roll"]),
                      (float(values["speed_ms"][0]), float(values["speed_ms"][1])))
        except (KeyError, TypeError, IndexError, ValueError) as e:
            raise ValueError(f"the axle boxes' response is damaged ({e})") from None
        if not len(out.freq_hz) == len(out.bounce) == len(out.roll) >= 2:
            raise ValueError("the axle boxes' response is damaged (curves of unequal length)")
        return out


def minimum_phase(gain: FloatArray) -> NDArray[np.complex128]:
    """The minimum-phase response with the magnitude ``gain`` given on an rfft grid (0 to the
    Nyquist frequency, an even transform length), by the folded real cepstrum."""
    full = np.concatenate([gain, gain[-2:0:-1]])
    n = len(full)
    cepstrum = np.fft.ifft(np.log(np.maximum(full, 1e-12))).real
    fold = np.zeros(n)
    fold[0], fold[1:n // 2], fold[n // 2] = 1.0, 2.0, 1.0
    return np.asarray(np.exp(np.fft.fft(cepstrum * fold))[: len(gain)])


def _block_spectra(pairs: Sequence[tuple[FloatArray, FloatArray, FloatArray]], fs: float
                   ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Every steady block's speed and the periodograms of its bounce and roll displacement:
    (f (F,), speeds (B,), bounce (B, F), roll (B, F))."""
    n = int(round(BLOCK_S * fs))
    window = get_window("hann", n)
    f = np.fft.rfftfreq(n, 1 / fs)
    to_displacement = 1.0 / np.maximum(2 * np.pi * f, 1e-9) ** 4
    speeds: list[float] = []
    sums: list[FloatArray] = []
    diffs: list[FloatArray] = []
    for left, right, speed in pairs:
        for a in range(0, len(speed) - n + 1, n // 2):
            v = np.abs(speed[a:a + n])
            if v.min() < MIN_BLOCK_SPEED or v.max() > STEADY * v.min():
                continue
            speeds.append(float(v.mean()))
            for out, x in ((sums, left[a:a + n] + right[a:a + n]),
                           (diffs, left[a:a + n] - right[a:a + n])):
                out.append(np.abs(np.fft.rfft((x - x.mean()) * window)) ** 2 * to_displacement)
    return (np.asarray(f, dtype=float), np.asarray(speeds, dtype=float),
            np.asarray(sums, dtype=float), np.asarray(diffs, dtype=float))


def _second_differences(n: int, offset: int, width: int) -> sparse.csr_matrix:
    i = np.arange(n - 2)
    rows = np.concatenate([i, i, i])
    cols = np.concatenate([i, i + 1, i + 2]) + offset
    vals = np.concatenate([np.ones(n - 2), -2 * np.ones(n - 2), np.ones(n - 2)])
    return sparse.csr_matrix((vals, (rows, cols)), shape=(n - 2, width))


def _interpolation(grid: FloatArray, x: FloatArray) -> tuple[NDArray[np.int64], FloatArray]:
    j = np.clip(np.searchsorted(grid, x) - 1, 0, len(grid) - 2)
    return j, np.clip((x - grid[j]) / (grid[j + 1] - grid[j]), 0.0, 1.0)


def _separate(f: FloatArray, speeds: FloatArray, power: FloatArray, f_high: float
              ) -> tuple[FloatArray, FloatArray]:
    """The response's log gain on a log grid of ``F_LOW_HZ``..``f_high`` from block
    periodograms ``power`` (B, F) at ``speeds`` (module docstring, step 1): (grid Hz, log
    gain)."""
    keep = (f >= F_LOW_HZ) & (f <= f_high)
    lf = np.log(f[keep])
    n_g = int(math.ceil(math.log2(f_high / F_LOW_HZ) * PER_OCTAVE_RESPONSE)) + 1
    g_grid = np.linspace(math.log(F_LOW_HZ), math.log(f_high), n_g)
    k_lo, k_hi = F_LOW_HZ / speeds.max(), f_high / speeds.min()
    n_s = int(math.ceil(math.log2(k_hi / k_lo) * PER_OCTAVE_TRACK)) + 1
    s_grid = np.linspace(math.log(k_lo), math.log(k_hi), n_s)
    jg, tg = _interpolation(g_grid, lf)
    n_f, n_b = len(lf), len(speeds)
    rows = np.arange(n_f * n_b)
    js, ts = _interpolation(s_grid, (lf[None, :] - np.log(speeds)[:, None]).ravel())
    jg, tg = np.tile(jg, n_b), np.tile(tg, n_b)
    width = n_g + n_s
    data = sparse.csr_matrix(
        (np.concatenate([2 * (1 - tg), 2 * tg, 1 - ts, ts]),
         (np.tile(rows, 4), np.concatenate([jg, jg + 1, n_g + js, n_g + js + 1]))),
        shape=(n_f * n_b, width))
    target = (np.log(power[:, keep] + 1e-300) + np.log(speeds)[:, None]).ravel()
    weight = math.sqrt(n_f * n_b / n_g)  # the smoothing's weight against the data's
    low = np.flatnonzero(g_grid < math.log(GAUGE_HZ))
    gauge = sparse.csr_matrix((np.full(len(low), 1e3 / len(low)), (np.zeros(len(low), int),
                                                                   low)), shape=(1, width))
    a = sparse.vstack([data, 0.3 * weight * _second_differences(n_g, 0, width),
                       weight * _second_differences(n_s, n_g, width), gauge])
    b = np.concatenate([target, np.zeros(n_g - 2 + n_s - 2), [0.0]])
    solution = lsqr(a, b, atol=1e-10, btol=1e-10, iter_lim=20000)[0]
    return np.exp(g_grid), solution[:n_g]


def identify(pairs: Sequence[tuple[FloatArray, FloatArray, FloatArray]], fs: float
             ) -> AxleResponse:
    """The wheelset's response (module docstring, steps 1-2) from recordings given as (left
    axle box, right axle box (m/s²), speed (m/s)) at the rate ``fs`` (Hz)."""
    f, speeds, bounce, roll = _block_spectra(pairs, fs)
    if len(speeds) < MIN_BLOCKS:
        raise RailwatchError(
            f"the axle boxes' response needs {MIN_BLOCKS} blocks of {BLOCK_S:g} s at a steady "
            f"speed above {MIN_BLOCK_SPEED:g} m/s, the training recordings have {len(speeds)}: "
            "give more recordings")
    ratio = speeds.max() / speeds.min()
    if ratio < MIN_SPEED_RATIO:
        raise RailwatchError(
            f"the axle boxes' response is told from the rails' texture by speed, and the "
            f"training recordings run at {speeds.min():.1f}-{speeds.max():.1f} m/s: give "
            f"recordings at speeds at least {MIN_SPEED_RATIO:g} times apart")
    f_high = ANTI_ALIAS_SHARE * fs
    grid, g_bounce = _separate(f, speeds, bounce, f_high)
    _, g_roll = _separate(f, speeds, roll, f_high)
    return AxleResponse(float(fs), tuple(grid.tolist()), tuple(g_bounce.tolist()),
                        tuple(g_roll.tolist()), (float(speeds.min()), float(speeds.max())))


def rail_heights(left: FloatArray, right: FloatArray, response: AxleResponse) -> FloatArray:
    """(2, n): the height (m) of the rail under the left and under the right wheel, from the
    two axle boxes' accelerations (m/s²), in the band :data:`F_LOW_HZ` to
    :data:`ANTI_ALIAS_SHARE` of the rate (module docstring, step 3)."""
    n = len(left)
    n_fft = 2 * ((n + 1) // 2)
    f = np.fft.rfftfreq(n_fft, 1 / response.fs)
    bounce, roll = response.transfer(n_fft)
    band = (f >= F_LOW_HZ) & (f <= ANTI_ALIAS_SHARE * response.fs)
    w2 = -(2 * np.pi * np.maximum(f, 1e-9)) ** 2
    x = np.fft.rfft(np.stack([left, right]).astype(np.float64), n_fft, axis=1)
    mean = np.where(band, (x[0] + x[1]) / (2 * w2 * bounce), 0.0)
    half_difference = np.where(band, (x[0] - x[1]) / (2 * w2 * roll), 0.0)
    return np.fft.irfft(np.stack([mean + half_difference, mean - half_difference]), n_fft,
                        axis=1)[:, :n]


def on_distance(heights: FloatArray, travelled: FloatArray, dx: float = DX_M
                ) -> tuple[float, FloatArray]:
    """Heights (2, n) at distances ``travelled`` (m, not decreasing) on a grid of ``dx``: each
    cell's mean, empty cells (a fast pass leaves some) interpolated. Returns (the first cell's
    distance, (2, cells))."""
    start = float(travelled[0])
    cell = np.floor((travelled - start) / dx).astype(np.int64)
    n = int(cell[-1]) + 1
    count = np.bincount(cell, minlength=n)
    full = np.flatnonzero(count)
    out = np.empty((2, n))
    for rail in range(2):
        mean = np.bincount(cell, weights=heights[rail], minlength=n)[full] / count[full]
        out[rail] = np.interp(np.arange(n), full, mean)
    return start + dx / 2, out


def shortest_wavelength(fs: float, speed: FloatArray) -> float:
    """The shortest wavelength (m) a pass measured everywhere: its 99th-percentile speed over
    the recorded band's top (:data:`ANTI_ALIAS_SHARE` of ``fs``), with a tenth to spare, and 2
    cm at least (the contact patch)."""
    return max(0.02, 1.1 * float(np.percentile(np.abs(speed), 99)) / (ANTI_ALIAS_SHARE * fs))
