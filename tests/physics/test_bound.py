"""The geometry bound (``railwatch.physics.bound``) against reference computations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import toeplitz

from railwatch.errors import RailwatchError
from railwatch.physics.bound import (
    RailSpectra,
    level,
    peaks,
    rail_spectra,
    track_geometry,
    weld_templates,
    whitened_scan,
)

DX, PHI = 0.01, 0.8
WIDE = (2 * DX, 1e9)  # every wavelength but the mean's


def ar1_spectra(n_freq: int = 4097) -> RailSpectra:
    """Two independent rails, each an AR(1) of unit innovations: E|X_k|²/N = 1/|1 − φe^{−iω}|²."""
    f = np.linspace(0.0, 1 / (2 * DX), n_freq)
    s = 1 / np.abs(1 - PHI * np.exp(-2j * np.pi * f * DX)) ** 2
    return RailSpectra(f, s, s.copy(), np.zeros(n_freq, dtype=complex))


def ar1(n: int, rng: np.random.Generator) -> np.ndarray:
    x = np.zeros(n)
    e = rng.normal(size=n)
    for t in range(1, n):
        x[t] = PHI * x[t - 1] + e[t]
    return x


def test_detectability_matches_the_covariance_matrix() -> None:
    """Noise-free input: ``z`` at the shape's start is d' = √(sᵀ C⁻¹ s), C the AR(1)'s
    covariance (Toeplitz, γ(h) = φ^|h| / (1 − φ²)), on either rail and either way of whitening."""
    shape = np.sin(2 * np.pi * np.arange(40) / 40)  # zero mean: the mean carries no weight
    n, at = 2048, 1000
    z = np.zeros((2, n))
    z[1, at:at + 40] = shape
    cov = toeplitz(PHI ** np.arange(n) / (1 - PHI**2))
    s = z[1]
    expected = float(np.sqrt(s @ np.linalg.solve(cov, s)))
    for both in (True, False):
        out = whitened_scan(z, ar1_spectra(), [shape], band_m=WIDE, both_rails=both)
        assert out[1, at] == pytest.approx(expected, rel=0.01)
        assert int(np.argmax(out[1])) == at


def test_z_is_standard_normal_where_there_is_no_defect() -> None:
    rng = np.random.default_rng(0)
    n = 1 << 15
    z = np.stack([ar1(n, rng), ar1(n, rng)])
    shape = np.hanning(60) - np.hanning(60).mean()
    out = whitened_scan(z, ar1_spectra(), [shape], band_m=WIDE)[:, 500:-500]
    assert abs(float(out.mean())) < 0.05
    assert float(out.std()) == pytest.approx(1.0, abs=0.05)


def test_the_other_rail_cancels_a_shared_profile() -> None:
    """Rails sharing most of their profile: whitening with the cross-spectrum sees a defect
    on one rail far better than each rail alone does."""
    rng = np.random.default_rng(1)
    n = 1 << 15
    shared = ar1(n, rng) * 10
    z = np.stack([shared + rng.normal(size=n), shared + rng.normal(size=n)])
    spectra = rail_spectra([z], dx=DX, segment=1024)
    assert np.median(np.abs(spectra.s12) / spectra.s11) > 0.9
    shape = np.sin(2 * np.pi * np.arange(50) / 50) * 3
    z[0, 20000:20050] += shape
    both = whitened_scan(z, spectra, [shape], band_m=WIDE)[0, 20000]
    one = whitened_scan(z, spectra, [shape], band_m=WIDE, both_rails=False)[0, 20000]
    assert both > 5 > one


def test_spectra_units_and_grid() -> None:
    rng = np.random.default_rng(2)
    z = rng.normal(0.0, 2.0, (2, 1 << 15))
    spectra = rail_spectra([z], dx=DX, segment=1024)
    assert np.median(spectra.s11) == pytest.approx(4.0, rel=0.1)  # σ² per bin and sample
    with pytest.raises(RailwatchError, match=r"must be \(2, n\)"):
        rail_spectra([z[0]])
    heights = track_geometry(np.arange(40.0).reshape(2, 20), 0.001, 0.005)
    assert heights.tolist() == [[2.0, 7.0, 12.0, 17.0], [22.0, 27.0, 32.0, 37.0]]


def test_level_peaks_and_templates() -> None:
    assert level([9.0, 7.0, 6.0, 5.0], km=20.0, per_km=0.1) == 7.0
    with pytest.raises(RailwatchError, match="simulate at least 10 km"):
        level([9.0], km=5.0, per_km=0.1)
    zmap = np.zeros((2, 2000))
    zmap[0, 100], zmap[1, 110], zmap[1, 1500] = 6.0, 5.0, 4.0
    assert peaks(zmap, apart_m=5.0).tolist()[:2] == [6.0, 4.0]  # 100 and 110: one place
    bank = weld_templates()
    assert len(bank) == 12 and min(float(t.min()) for t in bank) == pytest.approx(-1e-3, rel=0.02)


def test_the_cross_spectrum_s_phase() -> None:
    """The other rail a few samples behind: only the right phase of the cross-spectrum cancels
    the shared profile (a conjugated one would add it instead)."""
    rng = np.random.default_rng(3)
    n = 1 << 15
    shared = ar1(n + 8, rng) * 10
    z = np.stack([shared[8:] + rng.normal(size=n), shared[5:n + 5] + rng.normal(size=n)])
    spectra = rail_spectra([z], dx=DX, segment=1024)
    assert np.median(np.abs(spectra.s12.imag) / spectra.s11) > 0.05  # a delay: not real
    shape = np.sin(2 * np.pi * np.arange(50) / 50) * 3
    z[0, 20000:20050] += shape
    both = whitened_scan(z, spectra, [shape], band_m=WIDE)[0, 20000]
    one = whitened_scan(z, spectra, [shape], band_m=WIDE, both_rails=False)[0, 20000]
    assert both > 5 > one
