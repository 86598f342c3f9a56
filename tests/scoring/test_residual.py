"""GLR scoring of a residual: the change-point noise scale against a loop, and what it finds."""

from __future__ import annotations

import numpy as np

from railwatch.scoring import residual as R
from railwatch.scoring.residual import ResidualGLR, changepoint_scale


def brute_scale(r: np.ndarray, min_segment: int) -> np.ndarray:
    """The same estimate, one window and channel at a time, every split tried in a loop."""
    out = np.empty_like(r)
    n, t_len, c = r.shape
    for i in range(n):
        for ch in range(c):
            x = r[i, :, ch]
            s0 = np.median(np.abs(x)) / R.MAD_NORMAL
            sq = np.minimum(x * x, R.WINSOR * max(s0 * s0, 1e-24))
            total = -0.5 * t_len * np.log(max(sq.mean(), 1e-24))
            best, split = -np.inf, t_len
            for tau in range(min_segment, t_len - min_segment + 1):
                ll = -0.5 * (tau * np.log(max(sq[:tau].mean(), 1e-24))
                             + (t_len - tau) * np.log(max(sq[tau:].mean(), 1e-24)))
                if ll - total > best:
                    best, split = ll - total, tau
            if best <= R.PENALTY * np.log(t_len):
                split = t_len
            for part in (slice(0, split), slice(split, t_len)):
                seg = np.abs(x[part])
                if len(seg):
                    s = np.median(seg) / R.MAD_NORMAL
                    kept = seg[seg <= 3 * s]
                    out[i, part, ch] = np.sqrt(np.mean(kept**2) / R.TRIMMED_VARIANCE)
    return out


def test_changepoint_scale_matches_a_loop() -> None:
    rng = np.random.default_rng(0)
    levels = np.where(np.arange(120) < rng.integers(30, 90), 0.2, 1.0)
    r = rng.standard_normal((4, 120, 2)) * levels[None, :, None]
    r[1, :, 0] *= 0.3  # one without a step
    np.testing.assert_allclose(changepoint_scale(r, 30), brute_scale(r, 30), rtol=1e-9)


def test_finds_a_noise_step_and_invents_none() -> None:
    rng = np.random.default_rng(1)
    n, t_len = 300, 200
    where = rng.integers(40, 161, n)
    level = np.where(np.arange(t_len)[None, :] < where[:, None], 0.1, 0.5)  # (N, T)
    stepped = changepoint_scale((rng.standard_normal((n, t_len)) * level)[..., None])[..., 0]
    found = (stepped > 0.25).argmax(axis=1)
    assert np.mean(np.abs(found - where) <= 5) >= 0.9
    assert np.median(np.abs(stepped / level - 1)) < 0.1
    flat = changepoint_scale(rng.standard_normal((n, t_len, 1)))[..., 0]
    assert np.mean(flat.max(axis=1) / flat.min(axis=1) > 1.3) < 0.1  # no step invented


def test_scores_are_scale_and_offset_free_and_find_a_spike() -> None:
    rng = np.random.default_rng(2)
    r = rng.standard_normal((50, 200, 3))
    r[7, 123, 1] += 6.0
    glr = ResidualGLR(null_windows=500)
    ch = glr.channel_scores(r)
    assert ch.shape == r.shape and ch.dtype == np.float32
    np.testing.assert_allclose(glr.channel_scores(4.0 * r + 2.5), ch, rtol=1e-4, atol=1e-4)
    assert np.unravel_index(ch.argmax(), ch.shape) == (7, 123, 1)
    inst = ch.max(axis=(1, 2))
    assert inst[7] == inst.max() and np.median(inst) < 1.5  # -log10 p: about 1 under the null


def test_a_box_in_the_loud_part_of_a_stepped_window() -> None:
    """One noise level per window would drown a box that sits where the noise is low."""
    rng = np.random.default_rng(3)
    level = np.where(np.arange(200) < 100, 0.1, 0.5)
    r = rng.standard_normal((40, 200, 1)) * level[None, :, None]
    r[3, 40:52, 0] += 0.25  # 2.5 std of the quiet part, 0.5 of the loud, 0.7 of the window
    inst = ResidualGLR(null_windows=500).channel_scores(r).max(axis=(1, 2))
    assert inst.argmax() == 3 and inst[3] > 4  # p < 1e-4
    one_level = np.median(np.abs(r[3]), axis=0) / R.MAD_NORMAL  # what one level would give
    assert abs(r[3, 40:52, 0].sum()) / np.sqrt(12) / one_level[0] < 4


def test_greatest_of_is_the_louder_reference_cell_by_brute_force() -> None:
    rng = np.random.default_rng(3)
    sq = rng.exponential(size=(3, 60)) * rng.uniform(0.5, 4.0, size=(3, 1))
    got = R.greatest_of(sq, guard=4, ref=7)
    for b in range(3):
        for t in range(60):
            cells = [sq[b, max(0, t - 11):max(0, t - 4)], sq[b, t + 5:t + 12]]
            means = [c.mean() for c in cells if len(c)]
            assert np.isclose(got[b, t], max(means)) if means else np.isnan(got[b, t])
    assert np.isnan(R.greatest_of(sq[:, :5], guard=4, ref=7)).all()  # no cell: NaN
