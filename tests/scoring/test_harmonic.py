"""The harmonic nuisance model: its frequency, its fit against least squares, and what it leaves
of a defect."""

from __future__ import annotations

import numpy as np

from railwatch.scoring.harmonic import (
    chirp_rate,
    dominant_frequency,
    harmonic_design,
    harmonic_fit,
    oscillation,
    overtone_design,
    phase_break,
    robust_fit,
)


def drifting(rng: np.random.Generator, n: int = 200, f: float = 0.073) -> np.ndarray:
    """A sinusoid whose frequency drifts 4 % and amplitude 30 % over the window (a train
    accelerating), plus N(0, 0.2²) noise."""
    t = np.arange(n)
    phase = 2 * np.pi * f * (t + 0.02 * t ** 2 / n) + rng.uniform(0, 2 * np.pi)
    return 1.5 * (1 + 0.3 * t / n) * np.sin(phase) + 0.2 * rng.standard_normal(n)


def test_dominant_frequency_between_bins_and_despite_a_box() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(200)
    f = rng.uniform(0.01, 0.4, 50)
    x = np.sin(2 * np.pi * f[:, None] * t + rng.uniform(0, 6, (50, 1)))
    x += 0.1 * rng.standard_normal(x.shape)
    np.testing.assert_allclose(dominant_frequency(x), f, atol=0.002)
    x[:, 90:110] += 1.5  # a 20-sample box half the sinusoid's amplitude
    np.testing.assert_allclose(dominant_frequency(x), f, atol=0.003)


def test_unweighted_fit_is_least_squares_on_the_basis() -> None:
    rng = np.random.default_rng(1)
    x = np.stack([drifting(rng) for _ in range(4)])
    fit = harmonic_fit(x, poly=2, iterations=0, chirp=False)
    design = harmonic_design(200, dominant_frequency(x), 2).dense()
    for i in range(4):
        coef = np.linalg.lstsq(design[i], x[i], rcond=None)[0]
        np.testing.assert_allclose(fit[i], design[i] @ coef, atol=1e-6)


def test_residual_is_the_noise_and_keeps_a_box() -> None:
    """Must not fire: on a drifting sinusoid the residual is the noise. Must fire: a box of
    2 added on top stays in the residual nearly whole (the Huber weights keep it out of the
    fit)."""
    rng = np.random.default_rng(2)
    clean = np.stack([drifting(rng, f=f) for f in np.linspace(0.01, 0.33, 40)])
    resid = clean - harmonic_fit(clean)
    assert 0.17 < np.median(resid.std(axis=1)) < 0.21
    boxed = clean.copy()
    boxed[:, 120:135] += 2.0
    left = (boxed - harmonic_fit(boxed))[:, 120:135].mean(axis=1)
    assert np.median(left) > 1.8 and left.min() > 1.4


def test_chirp_rate_of_an_accelerating_train() -> None:
    """A frequency rising 6 % over the window (0.5 m/s² at 15 m/s) is measured; the chirped
    model then leaves no residual above the noise where a fixed frequency would."""
    rng = np.random.default_rng(3)
    t = np.arange(200)
    f0, rate = 0.3, 0.3 * 0.06 / 200
    x = np.stack([2 * np.sin(2 * np.pi * (f0 * t + rate * (t - 99.5) ** 2 / 2) + p)
                  for p in rng.uniform(0, 6, 20)]) + 0.05 * rng.standard_normal((20, 200))
    np.testing.assert_allclose(chirp_rate(x, dominant_frequency(x)), rate, rtol=0.2)
    chirped = np.abs(x - harmonic_fit(x)).max(axis=1)
    fixed = np.abs(x - harmonic_fit(x, chirp=False)).max(axis=1)
    assert np.median(chirped) < 0.25 < np.median(fixed)


def phase_kink_by_loop(x: np.ndarray, min_segment: int, step: int = 2, edge: int = 8) -> int:
    """The breakpoint of the continuous two-piece line fitted to the band-passed analytic
    signal's phase, by one least-squares fit per candidate."""
    n = len(x)
    spec = np.fft.fft(x)
    f = np.fft.fftfreq(n)
    peak = dominant_frequency(x[None, :])[0]
    analytic = np.fft.ifft(np.where((f > peak / 2) & (f < peak * 2), 2 * spec, 0))
    y = np.unwrap(np.angle(analytic))[edge:n - edge]
    t = np.arange(edge, n - edge, dtype=float)
    sse = {}
    for k in range(min_segment, n - min_segment + 1, step):
        design = np.stack([np.ones_like(t), t, np.maximum(t - k, 0)], axis=1)
        resid = y - design @ np.linalg.lstsq(design, y, rcond=None)[0]
        sse[k] = resid @ resid
    return min(sse, key=sse.get)


def speed_change(rng: np.random.Generator, n_series: int) -> tuple[np.ndarray, np.ndarray]:
    """The paper's speed change: frequency x U[0.5, 1.5] and amplitude x U[0.5, 1.5] at an
    instant in [40, 160), phase continuous; noise 0.1."""
    t = np.arange(200)
    at = rng.integers(40, 160, n_series)
    f1 = rng.uniform(0.03, 0.2, n_series)
    k = rng.choice([-1, 1], n_series) * rng.uniform(0.1, 0.5, n_series) + 1
    x = np.stack([np.where(t < c, np.sin(2 * np.pi * a * t),
                           rng.uniform(0.5, 1.5) * np.sin(2 * np.pi * (a * c + a * b * (t - c))))
                  for c, a, b in zip(at, f1, k, strict=True)])
    return x + 0.1 * rng.standard_normal(x.shape), at


def test_phase_break_equals_a_loop_and_finds_the_speed_change() -> None:
    x, at = speed_change(np.random.default_rng(4), 30)
    split, share = phase_break(x, 20)
    assert split.tolist() == [phase_kink_by_loop(row, 20) for row in x]
    assert np.mean(np.abs(split - at) <= 6) >= 0.9 and (share > 0.05).mean() >= 0.9


def test_a_speed_change_is_modelled_and_a_box_on_it_kept() -> None:
    """Must not fire: after a speed change the two-sided model leaves the noise. Must fire: a box
    of 1 (10 noise std) on it stays in the residual."""
    x, _ = speed_change(np.random.default_rng(5), 40)
    one = np.abs(x - harmonic_fit(x)).max(axis=1)
    two = np.abs(x - harmonic_fit(x, change=0.1)).max(axis=1)
    assert np.median(two) < 0.45 < np.median(one)
    boxed = x.copy()
    boxed[:, 100:115] += 1.0
    left = (boxed - harmonic_fit(boxed, change=0.1))[:, 100:115].mean(axis=1)
    assert np.median(left) > 0.85


def test_overtone_design_is_the_harmonics_below_nyquist() -> None:
    """The recurrence gives sin k φ and cos k φ of the basis' chirp, and nothing where k f is
    near or above Nyquist."""
    freq, rate = np.array([0.05, 0.2]), np.array([1e-5, -2e-5])
    t = np.arange(200.0)
    phase = 2 * np.pi * freq[:, None] * t + np.pi * rate[:, None] * (t - 99.5) ** 2
    cols = overtone_design(*oscillation(200, freq, rate), freq, 3).dense()
    for i, k in enumerate((2, 3, 4)):
        below = (k * freq < 0.45)[:, None]
        np.testing.assert_allclose(cols[:, :, 2 * i], np.sin(k * phase) * below, atol=1e-9)
        np.testing.assert_allclose(cols[:, :, 2 * i + 1], np.cos(k * phase) * below, atol=1e-9)
    assert not cols[1, :, 2:].any()  # 0.2 cycles per sample: the 3rd and 4th are above 0.45


def periodic(rng: np.random.Generator, n_series: int, shares: tuple[float, ...]) -> tuple[
        np.ndarray, np.ndarray]:
    """``n_series`` windows of a periodic vibration (a sinusoid of 1-10 cycles per 200
    samples with the harmonics at ``shares`` of its amplitude, random phases) and N(0, 0.2²)
    noise; returns the windows and the noise."""
    t = np.arange(200)
    f = rng.uniform(0.005, 0.05, (n_series, 1))
    x = 1.5 * np.sin(2 * np.pi * f * t + rng.uniform(0, 6, (n_series, 1)))
    for k, share in enumerate(shares, start=2):
        x += share * 1.5 * np.sin(2 * np.pi * k * f * t + rng.uniform(0, 6, (n_series, 1)))
    noise = 0.2 * rng.standard_normal(x.shape)
    return x + noise, noise


def test_overtones_model_a_periodic_vibration_and_leave_a_sinusoid_alone() -> None:
    """A vibration with harmonics leaves them in the residual of one sinusoid, and not with
    the overtones; on a sinusoid the overtones' test keeps the first model in nearly every
    series (the same fit), and a box on the vibration stays in the residual."""
    rng = np.random.default_rng(8)
    x, noise = periodic(rng, 300, (0.5, 0.25))
    plain = np.sqrt(((x - harmonic_fit(x) - noise) ** 2).mean(axis=1))
    rich = np.sqrt(((x - harmonic_fit(x, overtones=2) - noise) ** 2).mean(axis=1))
    assert np.median(plain) > 0.3 > 0.1 > np.median(rich), (np.median(plain), np.median(rich))
    x, _ = periodic(rng, 2000, ())
    same = np.all(harmonic_fit(x, overtones=2) == harmonic_fit(x), axis=1)
    assert same.mean() > 0.99, same.mean()
    x, _ = periodic(rng, 200, (0.5, 0.25))
    x[:, 90:110] += 1.0  # a box of 5 noise std
    r = x - harmonic_fit(x, overtones=2)
    kept = r[:, 90:110].mean(axis=1)
    assert np.median(kept) > 0.7, np.median(kept)


def test_weighted_fit_is_weighted_least_squares_on_the_basis() -> None:
    """With a level and no reweighting, the fit is least squares of x / level on the basis
    divided by it (the spectral peak taken from x / level), multiplied back; a level that is
    the same everywhere changes nothing."""
    rng = np.random.default_rng(5)
    x = np.stack([drifting(rng) for _ in range(4)])
    level = np.where(np.arange(200) < 120, 0.5, 2.0)[None, :] * rng.uniform(0.5, 2, (4, 1))
    fit = harmonic_fit(x, poly=2, iterations=0, chirp=False, level=level)
    design = harmonic_design(200, dominant_frequency(x / level), 2).dense()
    for i in range(4):
        coef = np.linalg.lstsq(design[i] / level[i, :, None], x[i] / level[i], rcond=None)[0]
        np.testing.assert_allclose(fit[i], design[i] @ coef, atol=1e-6)
    flat = np.full_like(x, 3.0)
    np.testing.assert_allclose(harmonic_fit(x, change=0.1, overtones=2, level=flat),
                               harmonic_fit(x, change=0.1, overtones=2), atol=1e-9)


def test_weighted_fit_finds_a_weak_vibration_beside_loud_track() -> None:
    """A window whose last two fifths are on loud track (noise 12 times the quiet part's): the
    vibration, 2.5 quiet noise std high, is below the loud part's noise, and unweighted the
    spectral peak is often the noise's; weighted by the noise's shape the model finds the
    vibration (must fire) and leaves a box on the quiet part whole (must not take it)."""
    rng = np.random.default_rng(6)
    n, t = 60, np.arange(200)
    std = np.where(t < 120, 0.1, 1.2)
    f = rng.uniform(0.02, 0.06, n)
    vib = 0.25 * np.sin(2 * np.pi * f[:, None] * t + rng.uniform(0, 6, (n, 1)))
    x = vib + std * rng.standard_normal((n, 200))
    level = np.broadcast_to(std, x.shape)
    quiet = slice(0, 120)

    def misfit(fit: np.ndarray) -> np.ndarray:
        return np.sqrt(((fit - vib)[:, quiet] ** 2).mean(axis=1)) / 0.1

    plain, weighted = harmonic_fit(x, change=0.1, overtones=2), \
        harmonic_fit(x, change=0.1, overtones=2, level=level)
    assert np.median(misfit(weighted)) < 0.5  # in quiet noise std: the vibration is modelled
    assert np.mean(misfit(plain) > 1.0) > 0.3  # unweighted, a third of the windows fit noise
    assert np.mean(misfit(weighted) > 1.0) < 0.05
    boxed = x.copy()
    boxed[:, 40:55] += 0.5  # a box of 5 quiet noise std: most of it stays (0.38 measured;
    # unweighted 0.41: the Huber threshold is set on the loud part's noise too)
    left = (boxed - harmonic_fit(boxed, change=0.1, overtones=2, level=level) - vib)[:, 40:55]
    assert np.median(left.mean(axis=1)) > 0.35


def test_design_normal_equations_and_fit_against_the_matrix() -> None:
    """The design's weighted normal equations and its fitted values equal those of its dense
    matrix (brute force), with carriers on disjoint spans (two sides: blocks of zeros), the
    constant, and overtones of degree 0; a robust fit with a level equals the weighted fit of
    the series over it."""
    rng = np.random.default_rng(9)
    n, split = 120, rng.integers(30, 90, 5)
    mask = np.arange(n)[None, :] < split[:, None]
    freq = rng.uniform(0.02, 0.2, 5)
    design = (harmonic_design(n, freq, 2, rng.uniform(-1e-4, 1e-4, 5))
              + harmonic_design(n, freq * 1.3, 1, None, mask)
              + harmonic_design(n, freq * 0.8, 1, None, ~mask)
              + overtone_design(*oscillation(n, freq), freq, 2))
    dense = design.dense()
    assert dense.shape == (5, n, design.width) == (5, n, 8 + 4 + 4 + 4)
    weights, y = rng.uniform(0.1, 2.0, (5, n)), rng.standard_normal((5, n))
    gram, rhs = design.normal_equations(weights, y)
    np.testing.assert_allclose(gram, np.einsum("btp,bt,btq->bpq", dense, weights, dense),
                               atol=1e-10)
    np.testing.assert_allclose(rhs, np.einsum("btp,bt,bt->bp", dense, weights, y), atol=1e-10)
    coef = rng.standard_normal((5, design.width))
    np.testing.assert_allclose(design.evaluate(coef), np.einsum("btp,bp->bt", dense, coef),
                               atol=1e-10)
    sides = design.rows(np.array([1, 3]))
    np.testing.assert_allclose(sides.dense(), dense[[1, 3]])
    level = rng.uniform(0.5, 3.0, (5, n))
    fit, _ = robust_fit(y, design, iterations=0, level=level)
    for i in range(5):
        coef_i = np.linalg.lstsq(dense[i] / level[i, :, None], y[i] / level[i], rcond=None)[0]
        np.testing.assert_allclose(fit[i], dense[i] @ coef_i, atol=1e-6)
    _, sigma = robust_fit(y, design, iterations=1, level=level)  # the first fit's scale
    np.testing.assert_allclose(sigma, 1.4826 * np.median(np.abs((y - fit) / level), axis=1)
                               + 1e-12)
