"""The GLR scan (railwatch.scoring.glr) against loops over every window, sample and box."""

from __future__ import annotations

import numpy as np
from scipy.special import ndtri

from railwatch.scoring.glr import (
    box_sums,
    covering_max,
    effective_counts,
    families,
    family_max,
    log10_familywise_p,
    scan,
)
from support import brute_family_max


def test_box_sums_and_covering_max_match_loops() -> None:
    rng = np.random.default_rng(0)
    g = rng.standard_normal((2, 30, 2))
    for L in (1, 5, 6, 20):
        sums = box_sums(g, L)
        assert sums.shape == (2, 30 - L + 1, 2)
        np.testing.assert_allclose(sums[1, 3, 1], g[1, 3:3 + L, 1].sum())
        cov = covering_max(sums, L)
        for t in range(30):
            starts = range(max(0, t - L + 1), min(t, 30 - L) + 1)
            np.testing.assert_allclose(cov[:, t], np.max([sums[:, s] for s in starts], axis=0))


def test_family_max_matches_brute_force() -> None:
    rng = np.random.default_rng(1)
    g = rng.standard_normal((2, 26, 2))
    for fam in families(5, 8):
        got = family_max(g, fam, [np.sqrt(L) for L in fam])
        np.testing.assert_allclose(got, brute_family_max(g, fam))


def test_familywise_p_is_monotone_and_continuous_across_branches() -> None:
    z = np.linspace(0.1, 60.0, 5000)
    lp = log10_familywise_p(z, 200.0)
    assert np.isfinite(lp).all() and (lp <= 0).all()
    assert np.all(np.diff(lp) <= 0)  # p saturates at 1 for small z ...
    tail = lp < -0.01
    assert np.all(np.diff(lp[tail]) < 0)  # ... and falls strictly in the tail
    z_switch = -ndtri(0.5e-8)  # where the stable branch (q < 1e-8) takes over: no jump there
    below, above = log10_familywise_p(np.array([z_switch - 1e-9, z_switch + 1e-9]), 200.0)
    assert abs(below - above) < 1e-6
    # single test: the two-sided normal tail; z = 1.96 -> p = 0.05
    np.testing.assert_allclose(log10_familywise_p(np.array([1.959964]), 1.0), np.log10(0.05),
                               atol=1e-5)


def test_effective_counts_spike_family_is_the_window_length() -> None:
    spike, box = effective_counts(200, families(5, 20), n_windows=4000, alpha=0.05, seed=0)
    assert 170 < spike < 230  # independent samples: m = T
    assert spike < box < sum(200 - L + 1 for L in range(5, 21))  # overlapping boxes


def test_scan_takes_one_residual_per_family() -> None:
    """A spike and the boxes may test residuals standardised by different noise scales: each
    family's profile comes from its own residual only."""
    rng = np.random.default_rng(3)
    g, other = rng.standard_normal((2, 5, 60, 2))
    fams, counts = families(5, 8), np.array([60.0, 40.0])
    norms = [[np.sqrt(L) for L in fam] for fam in fams]
    np.testing.assert_array_equal(scan([g, g], fams, norms, counts), scan(g, fams, norms, counts))
    mixed = scan([g, other], fams, norms, counts)
    spike_only = scan(g, fams[:1], norms[:1], counts[:1])
    box_only = scan(other, fams[1:], norms[1:], counts[1:])
    np.testing.assert_array_equal(mixed, np.maximum(spike_only, box_only))


def test_energy_family_is_calibrated_on_noise_and_finds_a_ringing_burst() -> None:
    from railwatch.scoring.glr import effective_energy_count, energy_z

    lengths = (8, 16, 32)
    m = effective_energy_count(200, lengths, 4000, 0.05, seed=0)
    assert 10 < m < 200  # fewer independent tries than positions: boxes overlap
    fresh = np.random.default_rng(1).standard_normal((4000, 200, 1))
    p = -log10_familywise_p(energy_z(fresh, lengths).max(axis=(1, 2)), m)
    assert 0.035 < np.mean(p > -np.log10(0.05)) < 0.065  # the calibration holds on new noise
    # A burst ringing at a quarter of the rate: its box sums cancel, its energy does not.
    w = np.random.default_rng(2).standard_normal((1, 200, 1))
    w[0, 100:132, 0] += 2.5 * np.sin(np.pi / 2 * np.arange(32))
    boxes = family_max(w, tuple(range(5, 21)), [np.sqrt(L) for L in range(5, 21)])
    ze = energy_z(w, lengths)
    assert ze[0, 100:132].max() > 6 and boxes[0].max() < 4.5
    assert 100 <= int(np.argmax(ze[0, :, 0])) < 132
