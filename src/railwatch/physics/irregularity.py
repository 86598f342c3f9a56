"""The rails' random unevenness: long-wave irregularity and short-wave roughness, as profiles.

Both are drawn from a one-sided power spectral density ``S(Ω)`` (m² per rad/m, Ω the wavenumber
in rad/m) as a sum of cosines with random phases, ``z(x) = Σ √(2 S(Ωₖ) ΔΩ) cos(Ωₖ x + φₖ)``,
evaluated for every Ωₖ of a grid at once by an inverse FFT (the same sum on a uniform grid).

- **Irregularity** (wavelengths 1–80 m): the German vertical-profile spectra (ORE B176),
  ``S = A·Ωc² / ((Ω² + Ωr²)(Ω² + Ωc²))``, low disturbance A = 4.032e-7 m·rad, high disturbance
  A = 1.080e-6 m·rad, Ωc = 0.8246 rad/m, Ωr = 0.0206 rad/m; or the FRA track classes 1–6,
  ``S = 0.25·A·Ωc² / (Ω²(Ω² + Ωc²))`` (A in cm²·rad/m, Ωc = 0.8245 rad/m). Both rails share the
  vertical profile; each adds half of a cross-level of its own, the German cross-level spectrum
  ``S = (A_g / b²)·Ωc²·Ω² / ((Ω² + Ωr²)(Ω² + Ωc²)(Ω² + Ωs²))`` (A_g = 5.32e-8 / 1.032e-7 m·rad,
  Ωs = 0.438 rad/m, b = 0.75 m), as a height difference.
- **Roughness** (wavelengths 0.8 mm–1 m): one-third-octave band levels in dB re 1 µm, each band's
  mean square spread evenly over its wavenumbers; per rail, independent. The default is the
  average network rail of the IMAGINE project (CNOSSOS-EU); ``iso3095`` is the limit of
  EN ISO 3095:2013 (a freshly ground rail).

Sources and checks: ``docs/physics.md``.

>>> x, z = profile(german_vertical("high"), 5000.0, 0.01, np.random.default_rng(0), (1.0, 80.0))
>>> bool(1e-3 < z.std() < 6e-3)  # a few mm rms
True
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from railwatch.errors import RailwatchError

FloatArray = NDArray[np.float64]
Spectrum = Callable[[FloatArray], FloatArray]

GERMAN = {"low": (4.032e-7, 5.32e-8), "high": (1.080e-6, 1.032e-7)}  # (A_v, A_g), m·rad
GERMAN_OMEGA_C, GERMAN_OMEGA_R, GERMAN_OMEGA_S, HALF_GAUGE = 0.8246, 0.0206, 0.438, 0.75
FRA_AV = {1: 1.2107, 2: 1.0181, 3: 0.6816, 4: 0.5376, 5: 0.2095, 6: 0.0339}  # cm²·rad/m
FRA_OMEGA_C = 0.8245

#: One-third-octave roughness levels (dB re 1 µm) by wavelength (mm), long to short.
ROUGHNESS_WAVELENGTHS_MM = (2000, 1600, 1250, 1000, 800, 630, 500, 400, 315, 250, 200, 160, 125,
                            100, 80, 63, 50, 40, 31.5, 25, 20, 16, 12.5, 10, 8, 6.3, 5, 4, 3.15,
                            2.5, 2, 1.6, 1.25, 1, 0.8)
ROUGHNESS_DB = {
    # IMAGINE average network rail (CNOSSOS-EU, RailwayCnossosEU_2020.json).
    "average": (35, 31, 28, 25, 23, 20, 17, 13.5, 10.5, 9.0, 6.5, 5.5, 5.0, 3.5, 2.0, 0.1, -0.2,
                -0.3, -0.8, -3.0, -5, -7, -8, -9, -10, -12, -13, -14, -15, -16, -17, -18, -19,
                -19, -19),
    # The EN ISO 3095:2013 limit (a reference track for noise tests).
    "iso3095": (17.1, 17.1, 17.1, 17.1, 17.1, 17.1, 17.1, 17.1, 15.0, 13.0, 11.0, 9.0, 7.0, 4.9,
                2.9, 0.9, -1.1, -3.2, -5.0, -5.6, -6.2, -6.8, -7.4, -8.0, -8.6, -9.2, -9.8,
                -10.4, -11.0, -11.6, -12.2, -12.8, -13.4, -14.0, -14.0),
}
IRREGULARITY_WAVELENGTHS_M = (1.0, 80.0)
ROUGHNESS_WAVELENGTHS_M = (0.0008, 1.0)


def german_vertical(level: str) -> Spectrum:
    """The German vertical-profile spectrum, ``level`` "low" or "high" disturbance."""
    a = GERMAN[level][0]

    def s(omega: FloatArray) -> FloatArray:
        w2 = omega**2
        return a * GERMAN_OMEGA_C**2 / ((w2 + GERMAN_OMEGA_R**2) * (w2 + GERMAN_OMEGA_C**2))

    return s


def german_cross_level(level: str) -> Spectrum:
    """The German cross-level spectrum as a height difference between the rails (m² per
    rad/m): the angle's spectrum times the gauge's square."""
    a = GERMAN[level][1]

    def s(omega: FloatArray) -> FloatArray:
        w2 = omega**2
        angle = a / HALF_GAUGE**2 * GERMAN_OMEGA_C**2 * w2 / (
            (w2 + GERMAN_OMEGA_R**2) * (w2 + GERMAN_OMEGA_C**2) * (w2 + GERMAN_OMEGA_S**2))
        return angle * (2 * HALF_GAUGE) ** 2

    return s


def fra_vertical(track_class: int) -> Spectrum:
    """The FRA vertical-profile spectrum of track class 1-6 (m² per rad/m)."""
    a = FRA_AV[track_class] * 1e-4

    def s(omega: FloatArray) -> FloatArray:
        w2 = np.maximum(omega**2, 1e-12)
        return 0.25 * a * FRA_OMEGA_C**2 / (w2 * (w2 + FRA_OMEGA_C**2))

    return s


def roughness(name: str) -> Spectrum:
    """A one-third-octave roughness spectrum as a density (m² per rad/m): each band's mean
    square over its wavenumber width, interpolated log-linearly between band centres."""
    levels = np.asarray(ROUGHNESS_DB[name], dtype=float)
    lam = np.asarray(ROUGHNESS_WAVELENGTHS_MM, dtype=float) * 1e-3
    centre = 2 * np.pi / lam  # rad/m, increasing
    width = centre * (2 ** (1 / 6) - 2 ** (-1 / 6))
    density = (1e-6 * 10 ** (levels / 20)) ** 2 / width

    def s(omega: FloatArray) -> FloatArray:
        safe = np.maximum(omega, 1e-9)
        return np.exp(np.interp(np.log(safe), np.log(centre), np.log(density)))

    return s


def irregularity_spectra(name: str) -> tuple[Spectrum, Spectrum | None]:
    """(vertical profile, cross-level or None) of a named irregularity: ``german-low``,
    ``german-high``, ``fra-1`` ... ``fra-6``."""
    if name in ("german-low", "german-high"):
        level = name.split("-")[1]
        return german_vertical(level), german_cross_level(level)
    if name.startswith("fra-") and name[4:].isdigit() and int(name[4:]) in FRA_AV:
        return fra_vertical(int(name[4:])), None
    raise RailwatchError(f"irregularity {name!r}: use german-low, german-high or fra-1 ... fra-6")


def profile(spectrum: Spectrum, length_m: float, dx: float, rng: np.random.Generator,
            band_m: tuple[float, float]) -> tuple[FloatArray, FloatArray]:
    """A random profile (m) of ``length_m`` at spacing ``dx`` with the one-sided spectrum
    ``spectrum`` between the wavelengths ``band_m`` (shortest, longest): the sum of cosines with
    random phases of the module docstring. Returns (x, z), both (n,)."""
    n = int(np.ceil(length_m / dx)) + 1
    n_fft = 1 << int(np.ceil(np.log2(max(n, 2))))
    d_omega = 2 * np.pi / (n_fft * dx)
    omega = np.arange(n_fft // 2 + 1) * d_omega
    keep = (omega >= 2 * np.pi / band_m[1]) & (omega <= 2 * np.pi / band_m[0])
    amp = np.zeros_like(omega)
    amp[keep] = np.sqrt(2 * spectrum(np.asarray(omega[keep], dtype=float)) * d_omega)
    phase = rng.uniform(0.0, 2 * np.pi, len(omega))
    # irfft of c_k gives (1/N) Σ (c_k e^{ikx} + conj): cos amplitude a_k needs c_k = N a_k / 2.
    z = np.fft.irfft(amp * n_fft / 2 * np.exp(1j * phase), n_fft)[:n]
    return np.arange(n, dtype=float) * dx, np.asarray(z, dtype=float)
