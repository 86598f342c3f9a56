"""What the track allows: a defect's detectability from the rails' own geometry.

The oracle of the physics bench knows each pass's clean twin, so it knows the track's
irregularity *as drawn* and finds every defect; no detector can know that. This bound knows
less, and what a detector could know: the track's **statistics** (the two rails' spectra and
their cross-spectrum, estimated on clean tracks) and the defect's **shape**, and it sees the
rails' height itself: no vehicle, no sensor noise, no speed. A vehicle is a linear filter of
that height plus noise, and repeated passes see the same height, so no detector whose
knowledge of the track is its statistics can do better from any number of passes (for a
Gaussian track, which the simulator's irregularity and roughness are; the static deflection's
soft and voided sleepers are in the spectra too).

The test is the whitened matched filter (the likelihood ratio of a shape of unknown size in
Gaussian noise of known spectrum), run over every position of both rails and a bank of shapes:
``t(τ) = Σ_k W_k* [Σ_k⁻¹ X_k]_r e^{iΩ_k τ} / N``, ``z = t / √(Σ_k |W_k|² [Σ_k⁻¹]_rr / N)``,
with ``X`` the two rails' DFT, ``Σ_k`` their 2×2 cross-spectral matrix and ``W`` the shape's DFT
on rail ``r``; ``z`` is N(0, 1) at every position where there is no defect, and its mean at the
defect is the defect's detectability ``d'``. Wavelengths outside :data:`BAND_M` get no weight (a
vehicle's accelerometers do not measure a rail's 100-m waves, and the profile grid's shortest
waves are the contact patch's). A threshold is set on clean tracks, for a number of false
places per km; a defect is found when the largest ``z`` near it clears it.

Used by ``benchmarks/physics.py`` ("What the track allows"); the derivation and its checks:
``docs/physics.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.signal import csd, find_peaks, welch

from railwatch.errors import RailwatchError
from railwatch.physics.features import Item

FloatArray = NDArray[np.float64]

#: The profile grid of the bound (m): the weld's shortest part, its crown, is 5-15 cm.
BOUND_DX_M = 0.01
#: Wavelengths (m) a vehicle's accelerometers can tell apart from the track at 10-30 m/s: 2 cm
#: (0.5-1.5 kHz, the axle box's anti-alias band) to 20 m (0.5-1.5 Hz, the body's AC coupling).
BAND_M = (0.02, 20.0)
#: Welds of the bank: every length and crown share the simulator draws from (``features``).
WELD_LENGTHS_M = (0.6, 0.8, 1.0, 1.2)
WELD_CROWNS = (0.0, 0.25, 0.5)  # of the dip's depth
WELD_CROWN_M = 0.1


@dataclass(frozen=True)
class RailSpectra:
    """Both rails' auto- and cross-spectra at frequencies ``freq`` (cycles per m), in the units of
    a DFT's expected power per sample (``E|X_k|² / N``): white noise of variance σ² is σ²."""

    freq: FloatArray
    s11: FloatArray
    s22: FloatArray
    s12: NDArray[np.complex128]  # E[X₁ X₂*] / N


def rail_spectra(profiles: Sequence[FloatArray], dx: float = BOUND_DX_M,
                 segment: int = 8192) -> RailSpectra:
    """Welch estimates of the rails' spectra, averaged over ``profiles`` (each (2, n), m)."""
    acc = []
    for z in profiles:
        if z.ndim != 2 or z.shape[0] != 2 or z.shape[1] < segment:
            raise RailwatchError(f"a profile must be (2, n) with n >= {segment}, not {z.shape}")
        f, s11 = welch(z[0], fs=1 / dx, nperseg=segment)
        _, s22 = welch(z[1], fs=1 / dx, nperseg=segment)
        _, s21 = csd(z[0], z[1], fs=1 / dx, nperseg=segment)  # scipy: E[X₁* X₂]
        acc.append((s11, s22, np.conj(s21)))
    s11, s22, s12 = (np.mean([a[i] for a in acc], axis=0) for i in range(3))
    half = 1 / (2 * dx)  # one-sided density (per cycle/m) -> power per DFT bin and sample
    return RailSpectra(np.asarray(f, dtype=float), np.asarray(s11.real * half),
                       np.asarray(s22.real * half), np.asarray(s12 * half))


def weld_templates(dx: float = BOUND_DX_M) -> list[FloatArray]:
    """The bank of weld shapes: ``features``' weld 1 mm deep (heights in m), for every length
    of :data:`WELD_LENGTHS_M` and crown share of :data:`WELD_CROWNS`."""
    out = []
    for length in WELD_LENGTHS_M:
        for crown in WELD_CROWNS:
            it = Item(0, "weld", 0.0, length, 1.0, 1, (("crown_mm", crown),
                                                        ("crown_m", WELD_CROWN_M)))
            out.append(it.height(np.arange(0.0, length + dx / 2, dx)))
    return out


def whitened_scan(z: FloatArray, spectra: RailSpectra, templates: Sequence[FloatArray],
                  dx: float = BOUND_DX_M, band_m: tuple[float, float] = BAND_M,
                  both_rails: bool = True) -> FloatArray:
    """(2, n): on each rail, the largest whitened matched-filter ``z`` over ``templates``, for
    the shape starting at each sample of ``z`` ((2, n) heights, m; module docstring).
    ``both_rails`` False whitens each rail by its own spectrum alone. Edge effects: the DFT is
    circular, so positions within the whitening filter's reach of an end are not valid."""
    n = z.shape[1]
    size = 1 << int(np.ceil(np.log2(n + max(len(t) for t in templates))))
    x = np.fft.fft(z - z.mean(axis=1, keepdims=True), size, axis=1)
    signed = np.fft.fftfreq(size, dx)
    f = np.abs(signed)
    s11 = np.interp(f, spectra.freq, spectra.s11)
    s22 = np.interp(f, spectra.freq, spectra.s22)
    s12 = np.interp(f, spectra.freq, spectra.s12.real) + 1j * np.interp(
        f, spectra.freq, spectra.s12.imag)
    s12 = np.where(signed < 0, np.conj(s12), s12)  # a real profile's spectrum is Hermitian
    band = (f >= 1 / band_m[1]) & (f <= 1 / band_m[0])
    if both_rails:
        det = np.where(band, s11 * s22 - np.abs(s12) ** 2, 1.0)
        whitened = [(s22 * x[0] - s12 * x[1]) / det, (s11 * x[1] - np.conj(s12) * x[0]) / det]
        weight = [s22 / det, s11 / det]  # the diagonal of Σ⁻¹
    else:
        whitened = [x[0] / np.where(band, s11, 1.0), x[1] / np.where(band, s22, 1.0)]
        weight = [1 / np.where(band, s11, 1.0), 1 / np.where(band, s22, 1.0)]
    out = np.full((2, n), -np.inf)
    for shape in templates:
        w = np.fft.fft(shape, size)
        for rail in range(2):
            t = np.fft.ifft(np.conj(w) * whitened[rail] * band).real[:n]
            var = float(np.sum(np.abs(w) ** 2 * weight[rail].real * band)) / size
            np.maximum(out[rail], t / np.sqrt(var), out=out[rail])
    return out


def peaks(zmap: FloatArray, dx: float = BOUND_DX_M, apart_m: float = 5.0) -> FloatArray:
    """The places of a (2, n) ``z`` map: its largest values over both rails at least
    ``apart_m`` apart (descending)."""
    top = zmap.max(axis=0)
    at, _ = find_peaks(top, distance=max(1, int(round(apart_m / dx))))
    return np.sort(top[at])[::-1]


def level(place_values: Sequence[float], km: float, per_km: float) -> float:
    """The threshold that ``per_km`` false places per km allow, from the places of clean tracks
    of ``km`` km in all (the value of the ``per_km · km``-th largest)."""
    k = int(np.floor(per_km * km))
    values = np.sort(np.asarray(place_values, dtype=float))[::-1]
    if k < 1 or k > len(values):
        raise RailwatchError(f"{km:g} km of clean track cannot set a level of {per_km:g} false "
                             f"places per km: simulate at least {1 / per_km:g} km")
    return float(values[k - 1])


def track_geometry(path: FloatArray, dx_from: float, dx: float = BOUND_DX_M) -> FloatArray:
    """A track's (2, n) rail heights on the bound's grid: means of ``dx / dx_from`` samples."""
    step = int(round(dx / dx_from))
    if step < 1 or abs(step * dx_from - dx) > 1e-9:
        raise RailwatchError(f"the bound's grid ({dx:g} m) must be a multiple of the track's "
                             f"({dx_from:g} m)")
    n = path.shape[1] // step * step
    return np.asarray(path[:, :n].reshape(2, -1, step).mean(axis=2))
