"""The whitened matched filter of weld shapes: the bank, the robust spectra, and ``z``'s law."""

from __future__ import annotations

import numpy as np
import pytest

from railwatch.scoring import dips


def test_a_weld_dips_by_its_depth_and_rises_by_its_crown() -> None:
    plain, crowned = dips.weld_shape(1.0, 0.0), dips.weld_shape(1.0, 0.5)
    mid = len(plain) // 2
    assert plain[mid] == pytest.approx(-1.0, abs=1e-3) and plain[0] == pytest.approx(0.0)
    assert crowned[mid] == pytest.approx(-0.5, abs=1e-3)  # the crown raises its centre
    assert np.allclose(plain[:20], crowned[:20])  # the crown is 10 cm at the centre only
    assert len(dips.weld_bank()) == len(dips.WELD_LENGTHS_M) * len(dips.WELD_CROWNS)


def test_robust_spectra_ignore_the_few_segments_with_a_defect() -> None:
    rng = np.random.default_rng(0)
    z = rng.normal(0.0, 1e-4, (2, 2 ** 17))
    for at in (20_000, 60_000, 100_000):  # three strong 0.5-m items in 16 segments
        z[:, at:at + 50] -= 5e-3
    mean = dips.rail_spectra([z], segment=8192)
    robust = dips.rail_spectra([z], segment=8192, robust=True)
    band = (robust.freq > 0.1) & (robust.freq < 1.5)
    # White noise has σ² per bin; three segments of 31 move the median a little, the mean 80-fold.
    assert np.median(robust.s11[band]) == pytest.approx(1e-8, rel=0.5)
    assert np.median(mean.s11[band]) > 20 * np.median(robust.s11[band])


def test_robust_spectra_keep_the_rails_coherence_and_stay_a_valid_matrix() -> None:
    """Rails that share most of their profile (coherence 0.81): the robust estimate keeps the
    cross-spectrum the mean gives and never puts the coherence above 1 (a median of the
    cross-spectrum's real and imaginary parts did: 1.08-1.11 on a rough physics track)."""
    rng = np.random.default_rng(1)
    common, own = rng.normal(0.0, 1.0, (2, 2 ** 18))
    z = np.stack([common + 0.33 * own, common - 0.33 * rng.normal(0.0, 1.0, 2 ** 18)])
    z[:, 50_000:50_080] += 40.0  # one strong item
    robust = dips.rail_spectra([z], segment=4096, robust=True)
    inner = slice(5, -5)
    coherence = np.abs(robust.s12) ** 2 / (robust.s11 * robust.s22)
    assert np.all(coherence[inner] <= 1.0 + 1e-9)
    assert np.median(coherence[inner]) == pytest.approx(1 / 1.1089 ** 2, abs=0.02)
    assert np.median(robust.s11[inner]) == pytest.approx(1.1089, rel=0.1)


def test_z_is_standard_normal_off_a_weld_and_its_detectability_at_one() -> None:
    """White heights of known spectrum: off the weld ``z`` is N(0, 1) (one template), and the
    weld adds its detectability d' = depth · ‖s‖ / σ to the ``z`` where it starts."""
    rng = np.random.default_rng(1)
    n, sigma = 2 ** 16, 2e-5
    noise = rng.normal(0.0, sigma, (2, n))
    shape = dips.weld_shape(0.8, 0.0)
    depth = 3e-5
    at = 30_000
    z = noise.copy()
    z[0, at:at + len(shape)] += depth * shape
    freq = np.linspace(0, 50, 200)
    white = dips.RailSpectra(freq, np.full(200, sigma ** 2), np.full(200, sigma ** 2),
                             np.zeros(200, complex))
    out = dips.whitened_scan(z, white, [shape], band_m=(0.02, 1e6))
    off = np.delete(out[1], range(at - 500, at + 500))
    assert np.mean(off) == pytest.approx(0.0, abs=0.05) and np.std(off) == pytest.approx(1.0,
                                                                                      rel=0.05)
    alone = dips.whitened_scan(noise, white, [shape], band_m=(0.02, 1e6))
    expected = depth * np.linalg.norm(shape) / sigma
    assert out[0, at] - alone[0, at] == pytest.approx(expected, rel=0.01)
