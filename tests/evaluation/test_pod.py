"""The hit/miss POD fit against a reference computation (Newton's method on the logistic
log-likelihood, the delta method by hand), and what it says when the data allow no fit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from railwatch.evaluation.pod import Z95, fit_pod


def newton_logistic(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Maximum likelihood of P(y=1) = 1/(1+exp(-(b0 + b1 x))) by Newton's method; the
    inverse of the observed information is the covariance."""
    X = np.stack([np.ones_like(x), x], axis=1)
    b = np.zeros(2)
    for _ in range(100):
        p = 1 / (1 + np.exp(-X @ b))
        info = X.T @ (X * (p * (1 - p))[:, None])
        step = np.linalg.solve(info, X.T @ (y - p))
        b += step
        if np.abs(step).max() < 1e-12:
            break
    p = 1 / (1 + np.exp(-X @ b))
    return b, np.linalg.inv(X.T @ (X * (p * (1 - p))[:, None]))


def test_pod_fit_matches_the_reference_computation() -> None:
    rng = np.random.default_rng(3)
    a = np.exp(rng.uniform(np.log(0.02), np.log(2.0), 400))
    true_b0, true_b1 = 4.0, 2.5  # a50 = exp(-1.6) = 0.20 mm
    y = rng.random(400) < 1 / (1 + np.exp(-(true_b0 + true_b1 * np.log(a))))
    fit = fit_pod(a, y)
    b, cov = newton_logistic(np.log(a), y.astype(float))
    assert (fit.beta0, fit.beta1) == pytest.approx(tuple(b), rel=1e-6)
    assert np.asarray(fit.cov) == pytest.approx(cov, rel=1e-5)
    l90 = (math.log(9) - b[0]) / b[1]
    g = np.array([-1 / b[1], -l90 / b[1]])
    assert fit.a90 == pytest.approx(math.exp(l90), rel=1e-6)
    assert fit.a90_95 == pytest.approx(math.exp(l90 + Z95 * math.sqrt(g @ cov @ g)), rel=1e-5)
    assert fit.a50 == pytest.approx(math.exp(-b[0] / b[1]), rel=1e-6)
    assert fit.a90 < fit.a90_95 and fit.pod(np.array([fit.a90]))[0] == pytest.approx(0.9)


def test_a90_95_bounds_the_true_a90_about_95_times_in_100() -> None:
    rng = np.random.default_rng(7)
    true_a90 = math.exp((math.log(9) - 4.0) / 2.5)
    covered = []
    for _ in range(200):
        a = np.exp(rng.uniform(np.log(0.02), np.log(2.0), 200))
        y = rng.random(200) < 1 / (1 + np.exp(-(4.0 + 2.5 * np.log(a))))
        covered.append(fit_pod(a, y).a90_95 >= true_a90)
    assert 0.88 <= np.mean(covered) <= 0.99


@pytest.mark.parametrize("sizes, hits, note", [
    (np.linspace(0.1, 1, 20), np.ones(20, bool), "all 20 found"),
    (np.linspace(0.1, 1, 20), np.zeros(20, bool), "none of 20 found"),
    (np.linspace(0.1, 1, 5), np.array([0, 1, 0, 1, 1], bool), "too few"),
    (np.linspace(0.1, 1, 20), np.arange(20) >= 10, "separate"),
])
def test_pod_says_when_the_data_allow_no_fit(sizes, hits, note) -> None:  # type: ignore[no-untyped-def]
    fit = fit_pod(sizes, hits)
    assert note in fit.note and math.isnan(fit.a90) and fit.describe() == fit.note
