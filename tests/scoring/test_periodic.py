"""The synchronous level of periodic impulses: against a loop, raised on a train of impulses,
not on a defect or on noise."""

from __future__ import annotations

import numpy as np
import pytest

from railwatch.scoring.periodic import null_power, period, synchronous_level

GUARD, CORRELATION = 1.25, 0.2


def loop_level(w: np.ndarray, per: float, guard: float, reach: int = 3, tol: int = 1
               ) -> np.ndarray:
    """:func:`synchronous_level` of one series at a given period, one sample at a time."""
    n = len(w)
    out = np.ones(n)
    for t in range(n):
        refs = []
        for k in [*range(-reach, 0), *range(1, reach + 1)]:
            c = t + int(np.rint(k * per))
            if 0 <= c < n:
                refs.append(max(w[j] ** 2 for j in range(max(0, c - tol), min(n, c + tol + 1))))
        if len(refs) >= 2:
            out[t] = max(1.0, np.sqrt(np.median(refs) / null_power(tol)) / guard)
    return out


def impulses(n: int, per: float, width: float, height: float, phase: float = 3.3) -> np.ndarray:
    """One-sided impulses ``height · exp(-(τ / width)²)`` every ``per`` samples."""
    tau = np.mod(np.arange(n) - phase, per)
    return height * np.exp(-(tau / width) ** 2) * (tau <= 3 * width)


def test_null_power_is_the_median_of_the_largest_square() -> None:
    rng = np.random.default_rng(0)
    for tol in (0, 1, 2):
        sims = (rng.standard_normal((200_000, 2 * tol + 1)) ** 2).max(axis=1)
        assert np.median(sims) == pytest.approx(null_power(tol), rel=0.02)


def test_against_a_loop() -> None:
    rng = np.random.default_rng(1)
    w = rng.standard_normal((4, 200)) + np.stack([impulses(200, p, 1.5, 6.0)
                                                  for p in (12.0, 23.4, 31.7, 47.0)])
    got = synchronous_level(w, 10, 50, GUARD, CORRELATION)
    per, rho = period(w, 10, 50)
    assert np.all(rho >= CORRELATION)  # trains this strong are periodic enough to be followed
    for i in range(4):
        np.testing.assert_allclose(got[i], loop_level(w[i], per[i], GUARD), rtol=1e-12)


@pytest.mark.parametrize("per", [12.0, 23.4, 41.3])
def test_the_period_of_a_train_of_impulses(per: float) -> None:
    rng = np.random.default_rng(2)
    w = rng.standard_normal((20, 200)) + impulses(200, per, 1.5, 5.0)
    found, _ = period(w, 10, 50)
    assert np.mean(np.abs(found - per) < 0.6) >= 0.9


def test_level_rises_on_the_impulses_and_not_between_them() -> None:
    rng = np.random.default_rng(3)
    train = impulses(200, 23.4, 1.5, 6.0)
    w = rng.standard_normal((100, 200)) + train
    level = synchronous_level(w, 10, 50, GUARD, CORRELATION)
    on = train > 3.0
    assert np.median(level[:, on]) > 2.5  # most of an impulse's 6 std is taken as level there
    assert np.median(level[:, ~on]) == 1.0
    # what the scan sees at the impulses is about noise-sized again
    assert np.median(np.abs(w / level)[:, on]) < 2.5


@pytest.mark.parametrize("kind", ["noise", "spike", "box"])
def test_a_defect_or_noise_keeps_its_level(kind: str) -> None:
    rng = np.random.default_rng(4)
    w = rng.standard_normal((200, 200))
    if kind == "spike":
        w[:, 100] += 6.0
    elif kind == "box":
        w[:, 100:112] += 2.0
    level = synchronous_level(w, 10, 50, GUARD, CORRELATION)
    assert np.mean(level == 1.0) > 0.95
    assert np.median(level[:, 100]) == 1.0  # the defect does not repeat a period later


def test_a_window_too_short_for_two_periods_keeps_its_level() -> None:
    w = np.random.default_rng(6).standard_normal((3, 18))
    np.testing.assert_array_equal(synchronous_level(w, 10, 50, GUARD, CORRELATION), 1.0)
