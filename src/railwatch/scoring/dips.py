"""The whitened matched filter of smooth dips on the rails' height: a weld's test.

A rail's height along the track (its irregularity, roughness and the dip of every support) is
Gaussian noise of a known spectrum to a first approximation, and a weld is a shape of unknown
depth in it: the likelihood-ratio test of that shape is the matched filter of the shape whitened
by the rails' spectra (both rails together: they share the vertical profile). Run over every
position of both rails and a bank of shapes, its ``z`` is N(0, 1) where there is no dip and
``d' = √(sᵀC⁻¹s)`` at one: ``t(τ) = Σ_k W_k* [Σ_k⁻¹ X_k]_r e^{iΩ_k τ} / N``, ``z = t / √(Σ_k
|W_k|² [Σ_k⁻¹]_rr / N)``, with ``X`` the two rails' DFT, ``Σ_k`` their 2×2 cross-spectral
matrix and ``W`` the shape's DFT on rail ``r``.

Two users: :mod:`railwatch.physics.bound` runs it on a simulated track's true height (what the
track allows), :mod:`railwatch.recordings.rails` on the height that a pass's axle boxes measured
(the map's weld evidence). Derivation and checks: ``docs/physics.md``, "What the track allows".
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.signal import csd, detrend, get_window, welch

from railwatch.errors import RailwatchError

FloatArray = NDArray[np.float64]

#: The profile grid (m): a weld's shortest part, its crown, is 5-15 cm.
DX_M = 0.01
#: Wavelengths (m) a vehicle's accelerometers can tell apart from the track at 10-30 m/s: 2 cm
#: (0.5-1.5 kHz, the axle box's anti-alias band) to 20 m (0.5-1.5 Hz, the body's AC coupling).
BAND_M = (0.02, 20.0)
#: The bank of weld shapes: a cosine dip over these lengths (m), with a crown at its centre of
#: these shares of its depth over :data:`CROWN_M` (the field-scale literature: welds dip 0.1-0.5
#: mm over about 1 m; the crown, a weld's ground bead, is our assumption: docs/physics.md).
WELD_LENGTHS_M = (0.6, 0.8, 1.0, 1.2)
WELD_CROWNS = (0.0, 0.25, 0.5)
CROWN_M = 0.1


@dataclass(frozen=True)
class RailSpectra:
    """Both rails' auto- and cross-spectra at frequencies ``freq`` (cycles per m), in the units of
    a DFT's expected power per sample (``E|X_k|² / N``): white noise of variance σ² is σ²."""

    freq: FloatArray
    s11: FloatArray
    s22: FloatArray
    s12: NDArray[np.complex128]  # E[X₁ X₂*] / N


def rail_spectra(profiles: Sequence[FloatArray], dx: float = DX_M, segment: int = 8192,
                 robust: bool = False) -> RailSpectra:
    """Welch estimates of the rails' spectra, averaged over ``profiles`` (each (2, n), m).
    ``robust``: the mean over the segments less the quarter that stand out most over all
    frequencies (:func:`_trimmed_spectra`), so that the few segments holding a defect or a
    turnout do not raise the whole track's spectrum."""
    acc = []
    for z in profiles:
        if z.ndim != 2 or z.shape[0] != 2 or z.shape[1] < segment:
            raise RailwatchError(f"a profile must be (2, n) with n >= {segment}, not {z.shape}")
        if robust:
            f, s11, s22, s12 = _trimmed_spectra(z, dx, segment)
            acc.append((s11, s22, s12))
            continue
        f, s11 = welch(z[0], fs=1 / dx, nperseg=segment)
        _, s22 = welch(z[1], fs=1 / dx, nperseg=segment)
        _, s21 = csd(z[0], z[1], fs=1 / dx, nperseg=segment)  # E[X₁* X₂]
        acc.append((s11, s22, np.conj(s21)))
    s11, s22, s12 = (np.mean([a[i] for a in acc], axis=0) for i in range(3))
    half = 1 / (2 * dx)  # one-sided density (per cycle/m) -> power per DFT bin and sample
    return RailSpectra(np.asarray(f, dtype=float), np.asarray(s11.real * half),
                       np.asarray(s22.real * half), np.asarray(s12 * half))


#: The robust spectra leave out this share of the segments: those that stand out most over all
#: frequencies, on both rails together.
TRIM = 0.25


def _trimmed_spectra(z: FloatArray, dx: float, segment: int
                     ) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.complex128]]:
    """Welch's one-sided densities of both rails (Hann segments, half overlapping), the mean of
    the segments' 2×2 periodograms less the :data:`TRIM` of segments that stand out most over
    all frequencies (each segment's mean log ratio of its power on both rails to the median
    segment's). Whole segments go, so the estimate stays a valid cross-spectral matrix with the
    rails' coherence (a median of the cross-spectrum's parts is no valid matrix: the coherence
    can exceed 1; trimming each frequency apart lowers the coherence), robust to the few
    segments that hold a defect or a turnout."""
    window = get_window("hann", segment)
    starts = range(0, z.shape[1] - segment + 1, segment // 2)
    spectra = np.stack([np.fft.rfft(detrend(z[:, s:s + segment], type="constant", axis=1)
                                    * window, axis=1) for s in starts])  # (S, 2, F)
    p11, p22 = np.abs(spectra[:, 0]) ** 2, np.abs(spectra[:, 1]) ** 2
    p12 = spectra[:, 0] * np.conj(spectra[:, 1])  # E[X₁ X₂*]
    total = (p11 + p22)[:, 1:-1] + 1e-300
    excess = np.mean(np.log(total / np.median(total, axis=0)), axis=1)
    keep = np.argsort(excess)[:max(1, int(round((1 - TRIM) * len(spectra))))]
    scale = 2.0 * dx / np.sum(window ** 2)  # one-sided density, per cycle/m
    mean = [p[keep].mean(axis=0) for p in (p11, p22, p12)]
    one_sided = np.ones(segment // 2 + 1)
    one_sided[0] = one_sided[-1] = 0.5  # DC and Nyquist are not doubled
    f = np.asarray(np.fft.rfftfreq(segment, dx), dtype=np.float64)
    return (f, np.asarray(mean[0].real * scale * one_sided, dtype=np.float64),
            np.asarray(mean[1].real * scale * one_sided, dtype=np.float64),
            np.asarray(mean[2] * scale * one_sided, dtype=np.complex128))


def weld_shape(length_m: float, crown_share: float, crown_m: float = CROWN_M,
               dx: float = DX_M) -> FloatArray:
    """A weld 1 m deep (heights in m, from its start): a cosine dip over ``length_m`` with a
    raised-cosine crown of ``crown_share`` of the depth over ``crown_m`` at its centre."""
    s = np.arange(0.0, length_m + dx / 2, dx)
    z = -0.5 * (1 - np.cos(2 * np.pi * s / length_m))
    c = (s - length_m / 2) / crown_m
    return np.asarray(z + crown_share * 0.5 * (1 + np.cos(np.pi * np.clip(c, -1, 1)))
                      * (np.abs(c) < 1))


def weld_bank(dx: float = DX_M) -> list[FloatArray]:
    """The detector's weld shapes: every length of :data:`WELD_LENGTHS_M` with every crown
    share of :data:`WELD_CROWNS`."""
    return [weld_shape(length, crown, dx=dx) for length in WELD_LENGTHS_M
            for crown in WELD_CROWNS]


def whitened_scan(z: FloatArray, spectra: RailSpectra, templates: Sequence[FloatArray],
                  dx: float = DX_M, band_m: tuple[float, float] = BAND_M,
                  both_rails: bool = True) -> FloatArray:
    """(2, n): on each rail, the largest whitened matched-filter ``z`` over ``templates``, for
    the shape starting at each sample of ``z`` ((2, n) heights, m; module docstring).
    ``both_rails`` False whitens each rail by its own spectrum alone. Wavelengths outside
    ``band_m`` get no weight. Edge effects: the DFT is circular, so positions within the
    whitening filter's reach of an end are not valid."""
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
