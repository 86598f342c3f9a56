"""The matched-filter baseline (docs/detectors.md, "Reference detectors: oracle and matched
filter")."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.metrics import roc_auc_score

from railwatch.detectors import create
from railwatch.detectors.matched_filter import (
    MatchedFilter,
    filter_correlate,
    noise_scale,
    prediction_error,
    robust_ar,
    template_norm,
)
from railwatch.errors import RailwatchError
from railwatch.scoring.glr import box_sums
from railwatch.synthetic import generate


def sinusoids(n: int, n_steps: int = 200, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(n_steps) / 100.0
    f, a = rng.uniform(1, 15, (n, 1)), rng.uniform(0.5, 2.0, (n, 1))
    return a * np.sin(2 * np.pi * f * t) + noise * rng.standard_normal((n, n_steps))


def test_template_norm_and_correlation_match_convolution_loops() -> None:
    rng = np.random.default_rng(0)
    c = rng.standard_normal((3, 5))
    w = rng.standard_normal((3, 40))
    g = filter_correlate(w, c)
    for b in range(3):
        for u in range(40):
            expect = sum(c[b, k] * w[b, u + k] for k in range(5) if u + k < 40)
            np.testing.assert_allclose(g[b, u], expect)
        for L in (1, 3, 5, 12):
            h = np.convolve(c[b], np.ones(L))  # the box seen through the prediction-error filter
            np.testing.assert_allclose(template_norm(c, L)[b], np.linalg.norm(h))
            # matched filter = inner product of w with the shifted template (box inside window)
            s = 7
            full = np.zeros(40)
            full[s:s + len(h)] = h
            np.testing.assert_allclose(box_sums(g[b][None, :, None], L)[0, s, 0], w[b] @ full)


def test_prediction_error_matches_a_loop_and_cancels_a_sinusoid() -> None:
    x = sinusoids(4)
    coef = robust_ar(x, order=4, huber_k=1.345, iterations=3, ridge=1e-9)
    e = prediction_error(x, coef)
    a, b = coef[:, :4], coef[:, 4]
    for i in range(4):
        for t in range(200):
            if t >= 4:
                pred = sum(a[i, k - 1] * x[i, t - k] for k in range(1, 5)) + b[i]
            else:
                pred = sum(a[i, k - 1] * x[i, t + k] for k in range(1, 5)) + b[i]
            np.testing.assert_allclose(e[i, t], x[i, t] - pred, atol=1e-9)
    assert np.abs(e).max() < 1e-3  # a sinusoid is an exact linear recursion


def test_robust_predictor_is_pulled_less_by_the_anomaly() -> None:
    x = sinusoids(50, noise=0.1, seed=1)
    bumped = x.copy()
    bumped[:, 90:105] += 2.0  # a 15-sample local deviation of 20 noise stds
    bumped[:, 150] += 4.0  # and a spike

    def excess(huber_k: float, iterations: int) -> float:
        """Extra prediction error on the clean series from fitting on the anomalous one."""
        fitted_on_bumped = robust_ar(bumped, 8, huber_k, iterations, 1e-6)
        fitted_on_clean = robust_ar(x, 8, huber_k, iterations, 1e-6)
        return float(np.median(np.abs(prediction_error(x, fitted_on_bumped)))
                     - np.median(np.abs(prediction_error(x, fitted_on_clean))))

    plain, robust = excess(np.inf, 0), excess(1.345, 4)
    assert 0 < robust < 0.85 * plain  # measured 0.022 against 0.030


def test_noise_scale_finds_the_change_point() -> None:
    rng = np.random.default_rng(2)
    e = rng.standard_normal((200, 200))
    e[:, 120:] *= 3.0
    e[:, 60] += 30.0  # an outlier must not move the split
    scale = noise_scale(e, min_segment=20, winsor=3.0)
    np.testing.assert_allclose(np.median(scale[:, :110], axis=0), 1.0, atol=0.1)
    np.testing.assert_allclose(np.median(scale[:, 130:], axis=0), 3.0, atol=0.3)


def test_fit_standardises_each_channel_without_labels() -> None:
    train = generate(3, 200, seed=0)
    det = create("matched-filter", {"progress": False, "null_windows": 500}).fit(train.X)
    peak = det.score(train.X).channel.max(axis=1)  # (N, C)
    np.testing.assert_allclose(np.median(peak, axis=0), 0.0, atol=1e-5)


def test_scores_do_not_depend_on_the_chunk_size(monkeypatch: pytest.MonkeyPatch) -> None:
    """The series are scored in chunks that keep the predictor's design in the cache; a chunk
    of one window, or of all of them, gives the same scores (to rounding: the batched linear
    algebra sums in another order)."""
    from railwatch.detectors import matched_filter

    data = generate(3, 200, seed=1)
    det = create("matched-filter", {"progress": False, "null_windows": 500}).fit(data.X)
    monkeypatch.setattr(matched_filter, "CHUNK_BYTES", 1)  # one window per chunk
    one = det.raw_scores(data.X[:40])
    monkeypatch.setattr(matched_filter, "CHUNK_BYTES", 1 << 40)  # every window in one chunk
    np.testing.assert_allclose(det.raw_scores(data.X[:40]), one, rtol=1e-9, atol=1e-12)


@pytest.mark.slow
def test_matched_filter_stage_1_floor() -> None:
    train, test = generate(1, 2000, seed=0), generate(1, 1000, seed=1)
    det = create("matched-filter", {"progress": False}).fit(train.X)
    assert roc_auc_score(test.y, det.score(test.X).instance) >= 0.93  # measured 0.950


def band_limited(n: int, seed: int, spike: bool) -> tuple[np.ndarray, np.ndarray]:
    """Windows as a recording gives them: a sinusoid (up to 33 Hz) and white noise at 2000 Hz,
    a 0.01-s defect of 1.5 in half of them, resampled to 100 Hz by the recordings' filter
    (nothing above 40 Hz); (n, 200, 1) windows and each defect's sample."""
    from railwatch.recordings.prepare import Resampler

    rng = np.random.default_rng(seed)
    t = np.arange(4000) / 2000.0
    f, a = rng.uniform(1, 33, (n, 1)), rng.uniform(0.5, 2.5, (n, 1))
    raw = (a * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi, (n, 1)))
           + rng.uniform(0.1, 1.0, (n, 1)) * rng.standard_normal((n, 4000)))
    at = rng.integers(1000, 3000, n)
    if spike:
        for i in range(n):
            raw[i, at[i]:at[i] + 20] += 1.5 * rng.choice([-1.0, 1.0])
    resampler = Resampler(1, 20, n)  # every window a channel: one pass of the filter
    out = np.concatenate([resampler.push(raw.T.astype(np.float32)), resampler.flush()])
    return out[:200].T[:, :, None].copy(), at // 20


def test_ridge_keeps_the_predictor_stable_on_resampled_recordings() -> None:
    """An unloaded predictor whitens the empty band above the resampling filter's cut-off
    into unstable filters; the default ridge finds the defect as the top of its window far
    more often (docs/notes/2026-12-03-track-map-how-we-got-here.md, "Where the per-pass loss
    came from")."""
    train, _ = band_limited(300, 0, spike=False)
    X, at = band_limited(300, 1, spike=True)

    def top_share(ridge: float) -> float:
        det = create("matched-filter", {"progress": False, "null_windows": 500,
                                        "ridge": ridge}).fit(train)
        ch = det.score(X).channel[:, :, 0]
        return float(np.mean([
            ch[i, max(0, k - 2):k + 3].max() > np.delete(ch[i], np.r_[max(0, k - 10):k + 11]).max()
            for i, k in enumerate(at)]))

    default = top_share(create("matched-filter").config.ridge)
    assert default >= 0.92 and default >= top_share(1e-6) + 0.08  # measured 0.96 against 0.82


def test_field_scale_defaults_follow_the_rate_and_bad_lengths_are_one_line() -> None:
    assert MatchedFilter.field_scale(2000.0) == {"order": 16, "energy_boxes": (8, 16, 32, 64),
                                                 "change_point": False}
    assert MatchedFilter.field_scale(5000.0)["order"] == 32  # at most 32 taps
    assert MatchedFilter.field_scale(100.0)["order"] == 8  # at least the spec's
    det = create("matched-filter", {"energy_boxes": "8,x"})
    with pytest.raises(RailwatchError, match="energy_boxes must be box lengths"):
        det.fit(np.zeros((4, 64, 1), dtype=np.float32))
