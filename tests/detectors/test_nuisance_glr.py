"""nuisance-glr: where it must and must not fire, and the noise floor's calibration of loud
stretches."""

from __future__ import annotations

import numpy as np
import pytest

from railwatch.detectors import create
from railwatch.errors import RailwatchError
from railwatch.recordings.floor import NOISE_FLOOR


def windows(rng: np.random.Generator, n: int, loud: bool = False,
            ) -> tuple[np.ndarray, np.ndarray]:
    """``n`` two-channel windows of 200 samples: a sinusoid and white noise of std 0.2, with
    ``loud``, 4x louder over steps 40-80 and 120-160 (a level that steps four times, as a
    recording's does every 0.4-1.6 s); and their noise power per sample (the floor)."""
    t = np.arange(200)
    f = rng.uniform(0.01, 0.3, (n, 1, 2))
    x = rng.uniform(0.5, 2, (n, 1, 2)) * np.sin(2 * np.pi * f * t[None, :, None]
                                                 + rng.uniform(0, 6, (n, 1, 2)))
    std = np.full((n, 200, 2), 0.2)
    if loud:
        std[:, 40:80] *= 4
        std[:, 120:160] *= 4
    return (x + std * rng.standard_normal(x.shape)).astype(np.float32), \
        (std ** 2).astype(np.float32)


@pytest.fixture(scope="module")
def fitted():  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(0)
    X, floor = windows(rng, 120)
    det = create("nuisance-glr", {"null_windows": 2000})
    return det.fit(X, {NOISE_FLOOR: floor}), det


def test_fires_on_a_box_and_a_spike_where_they_are(fitted) -> None:  # type: ignore[no-untyped-def]
    det, _ = fitted
    rng = np.random.default_rng(1)
    X, floor = windows(rng, 40)
    clean = det.score(X, {NOISE_FLOOR: floor})
    hit = X.copy()
    hit[:20, 80:95, 1] += 1.0  # a box of 5 noise std on channel 1
    hit[20:, 150, 0] += 1.6  # a spike of 8 noise std on channel 0
    s = det.score(hit, {NOISE_FLOOR: floor})
    assert (s.instance > clean.instance).all()
    assert (s.instance[:20] > np.quantile(clean.instance, 0.95)).mean() >= 0.9
    peak_t, peak_c = s.point.argmax(axis=1), s.channel.max(axis=1).argmax(axis=1)
    assert (np.abs(peak_t[:20] - 87) <= 10).mean() >= 0.9 and (peak_c[:20] == 1).all()
    assert (np.abs(peak_t[20:] - 150) <= 1).mean() >= 0.9 and (peak_c[20:] == 0).all()


def test_the_floor_holds_the_false_rate_on_loud_track(fitted) -> None:  # type: ignore[no-untyped-def]
    """Windows whose noise turns 4x louder and back twice: with the floor their scores stay
    those of quiet windows; without it (a level with at most one change per window) the loud
    stretches fire. And a defect on a quiet stretch is found with the floor."""
    det, _ = fitted
    rng = np.random.default_rng(2)
    quiet, qf = windows(rng, 200)
    loud, lf = windows(rng, 200, loud=True)
    threshold = np.quantile(det.score(quiet, {NOISE_FLOOR: qf}).instance, 0.9)
    assert (det.score(loud, {NOISE_FLOOR: lf}).instance > threshold).mean() < 0.2
    blind = create("nuisance-glr", {"null_windows": 2000}).fit(quiet)
    blind_threshold = np.quantile(blind.score(quiet).instance, 0.9)
    assert (blind.score(loud).instance > blind_threshold).mean() > 0.5
    hit = loud.copy()
    hit[:, 90:100, 0] += 0.6  # a box of 3 quiet-noise std on the quiet stretch between
    found = (det.score(hit, {NOISE_FLOOR: lf}).instance > threshold).mean()
    assert found > (blind.score(hit).instance > blind_threshold).mean() - 0.3 and found > 0.8


def test_scored_as_it_was_fitted(fitted) -> None:  # type: ignore[no-untyped-def]
    det, _ = fitted
    X, floor = windows(np.random.default_rng(3), 3)
    with pytest.raises(RailwatchError, match="fitted with noise_floor but is scored with none"):
        det.score(X)
    blind = create("nuisance-glr", {"null_windows": 2000}).fit(X)
    with pytest.raises(RailwatchError, match="fitted with no side array"):
        blind.score(X, {NOISE_FLOOR: floor})


def coloured(rng: np.random.Generator, n: int, steps: int = 400) -> np.ndarray:
    """``n`` two-channel windows of a resonance (AR(2) noise ringing at 0.05 cycles per sample,
    pole radius 0.95: the track's response at field scale, not a sinusoid) plus white noise."""
    from scipy.signal import lfilter

    a = [1.0, -2 * 0.95 * np.cos(2 * np.pi * 0.05), 0.95 ** 2]
    drive = rng.standard_normal((n, steps + 200, 2))
    return (lfilter([1.0], a, drive, axis=1)[:, 200:] * 0.3
            + 0.2 * rng.standard_normal((n, steps, 2))).astype(np.float32)


def test_at_field_scale_the_predictor_alone_is_the_matched_filter() -> None:
    """With the harmonic model off, nuisance-glr's field-scale whitening, energy family and
    noise scale give the matched filter's raw scores (the same steps, brute reference)."""
    from railwatch.detectors.matched_filter import MatchedFilter
    from railwatch.detectors.nuisance_glr import NuisanceGLR

    X = coloured(np.random.default_rng(4), 12)
    X[3, 200:210, 1] += 2.0
    settings = {"null_windows": 500, "irls_iterations": 4}
    field = NuisanceGLR.field_scale(2000.0)
    assert field["order"] == 16 and field["energy_boxes"] == (8, 16, 32, 64)
    assert field["bursts"] is False and field["change"] == 0 and field["period_guard"] == 0
    ng = create("nuisance-glr", {**settings, **field, "harmonic": False}).fit(X)
    mf = create("matched-filter", {**settings, **MatchedFilter.field_scale(2000.0)}).fit(X)
    np.testing.assert_allclose(ng.raw_scores(X), mf.raw_scores(X), rtol=1e-6, atol=1e-9)


def test_at_field_scale_a_coloured_response_is_whitened() -> None:
    """On a resonance instead of a sinusoid, the benchmark's settings leave the colour in the
    residual and miss an impact (a squat at field scale) that the field-scale settings find,
    each at its threshold of 5 % of clean windows."""
    from railwatch.detectors.nuisance_glr import NuisanceGLR

    rng = np.random.default_rng(5)
    train, clean, hit = coloured(rng, 60), coloured(rng, 200), coloured(rng, 200)
    hit[:, 200, 0] += 4.0  # under 2 std of the resonance, 11 of what the predictor leaves

    def found(settings: dict[str, object]) -> float:
        det = create("nuisance-glr", {"null_windows": 1000, **settings}).fit(train)
        threshold = np.quantile(det.score(clean).instance, 0.95)
        return float((det.score(hit).instance > threshold).mean())

    field, bench = found(NuisanceGLR.field_scale(2000.0)), found({})
    assert field > 0.9 and field > bench + 0.2, (field, bench)


def test_without_a_floor_the_level_is_the_change_points() -> None:
    """Without a floor, the noise level is the change point's two trimmed scales, one per side:
    a window-wide MAD on top (as a floor's shape needs) only adds its own error. On 4,000
    windows whose noise steps from 0.3 to 0.6 at sample 90, the level's rms log error is 0.122;
    with the MAD on top it was 0.135."""
    from railwatch.detectors.nuisance_glr import noise_level
    from railwatch.scoring.residual import changepoint_scale

    true = np.r_[np.full(90, 0.3), np.full(110, 0.6)]
    r = np.random.default_rng(5).standard_normal((4000, 200)) * true
    level = noise_level(r, None)
    np.testing.assert_array_equal(level, changepoint_scale(r[:, :, None])[:, :, 0])
    error = np.sqrt(np.mean(np.log(level / true) ** 2))
    assert error < 0.128, error
    one = noise_level(r, None, change=False)  # no change point: one scale per window
    assert np.allclose(one, one[:, :1]) and abs(np.median(one) / 0.47 - 1) < 0.1


def test_with_impulses_the_train_is_taken_out_and_the_harmonic_fitted_again() -> None:
    """``impulses``: a sinusoid with a wheel's impulse train (one-sided Gaussians, 6 noise std,
    every 23.4 samples) and a box: the train found and taken out (the harmonic model fitted
    again to the series less it), the box left for the scan."""
    from railwatch.detectors.nuisance_glr import NuisanceGLR

    rng = np.random.default_rng(6)
    t = np.arange(200)
    tau = np.mod(t - 2.6, 23.4)
    train = 6.0 * np.exp(-(tau / 2.0) ** 2) * (tau <= 6.0)
    x = 3.0 * np.sin(2 * np.pi * 0.012 * t + 0.4) + train + rng.standard_normal((40, 200))
    x[:, 101:111] -= 5.0  # a box between two impulses
    det = NuisanceGLR(impulses=True)
    r = x - det.nuisance(x)
    _, _, taken = det.whitened(r, None)
    assert (taken.any(axis=1)).mean() >= 0.9
    assert np.sqrt(np.mean((taken - train) ** 2)) < 1.0  # of a train up to 6 noise std high
    w, _ = det.residual(x, None)
    off, _ = NuisanceGLR().residual(x, None)
    impulse = np.abs(train) > 3
    assert np.abs(w[:, impulse]).mean() < 0.7 * np.abs(off[:, impulse]).mean()
    assert np.median(w[:, 101:111].mean(axis=1)) < -3.0  # the box stays


def stage_auc(stage: int) -> float:
    from sklearn.metrics import roc_auc_score

    from railwatch.synthetic import generate

    train, test = generate(stage, 500, seed=0), generate(stage, 500, seed=1)
    det = create("nuisance-glr", {"null_windows": 2000, "progress": False}).fit(train.X)
    return float(roc_auc_score(test.y, det.score(test.X).instance))


# Measured 2026-12-06 (Intel Xeon, 2 cores): 0.980 at stage 1 and 0.768 at stage 8 (3 s each;
# 0.733 before the burst model and the impulses' synchronous level, which the stage-8 floor
# would fail). The floors leave room for platform noise.
@pytest.mark.slow
def test_auc_floor_stage1() -> None:
    assert stage_auc(1) >= 0.96


@pytest.mark.slow
def test_auc_floor_stage8() -> None:
    assert stage_auc(8) >= 0.74
