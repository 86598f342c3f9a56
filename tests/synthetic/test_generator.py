"""The benchmark generator against its definition in docs/benchmark.md."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from railwatch.synthetic import components as comp
from railwatch.synthetic import generate, stage
from railwatch.synthetic.anomalies import LOCAL, SPIKE, round_half_up
from railwatch.synthetic.stages import GROUPS, P_LOCAL, P_SPIKE

CHANNELS = {1: 1, 2: 1, 3: 2, 4: 2, 5: 6, 6: 6, 7: 6, 8: 6}
RANDOM_VARIABLES = {1: 3, 2: 6, 3: 14, 4: 18, 5: 54, 6: 54, 7: 84, 8: 102}
stages_ = st.integers(1, 8)


@pytest.mark.parametrize("number", range(1, 9))
def test_shapes_channels_and_dtypes(number: int) -> None:
    d = generate(number, 30, seed=1)
    assert d.X.shape == (30, 200, CHANNELS[number]) and d.X.dtype == np.float32
    assert d.mask.shape == d.X.shape and d.mask.dtype == bool
    assert d.y.shape == d.kind.shape == d.channel.shape == (30,)
    assert np.isfinite(d.X).all()
    assert d.meta["n_channels"] == CHANNELS[number] == len(d.meta["channel_names"])


@pytest.mark.parametrize("number", range(1, 9))
def test_random_variable_counts_are_recorded(number: int) -> None:
    d = generate(number, 5, seed=0)
    per_channel = [k for k, v in d.params.items() if v.ndim == 2]
    assert all(d.params[k].shape == (5, CHANNELS[number]) for k in per_channel)
    assert len(per_channel) * CHANNELS[number] == RANDOM_VARIABLES[number]
    assert d.meta["n_random_variables"] == stage(number).n_random_variables
    assert d.meta["n_random_variables"] == RANDOM_VARIABLES[number]


@settings(max_examples=25, deadline=None)
@given(number=stages_, n=st.integers(1, 400), seed=st.integers(0, 2**32 - 1))
def test_exact_anomaly_counts_and_shapes(number: int, n: int, seed: int) -> None:
    d = generate(number, n, seed)
    assert d.y.sum() == round_half_up(0.1 * n)
    assert (d.kind == SPIKE).sum() == min(round_half_up(0.05 * n), round_half_up(0.1 * n))
    assert (d.kind == LOCAL).sum() == d.y.sum() - (d.kind == SPIKE).sum()
    assert np.array_equal(d.y, d.kind != 0)
    # Normal windows carry nothing; anomalous ones exactly one channel.
    assert not d.mask[d.y == 0].any() and (d.channel[d.y == 0] == -1).all()
    touched = d.mask.any(axis=1)  # (n, C)
    assert (touched.sum(axis=1)[d.y == 1] == 1).all()
    assert np.array_equal(touched[d.y == 1].argmax(axis=1), d.channel[d.y == 1])
    lengths = d.mask.sum(axis=(1, 2))
    assert (lengths[d.kind == SPIKE] == 1).all()
    assert ((lengths[d.kind == LOCAL] >= 5) & (lengths[d.kind == LOCAL] <= 20)).all()
    # Each span is contiguous.
    for i in np.flatnonzero(d.y):
        idx = np.flatnonzero(d.mask[i, :, d.channel[i]])
        assert idx[-1] - idx[0] + 1 == idx.size


def test_offsets_in_range_with_both_signs_and_added_to_the_signal() -> None:
    d = generate(5, 4000, seed=3, components=True)
    off = d.params["anomaly_offset"]
    spikes, local = np.abs(off[d.kind == SPIKE]), np.abs(off[d.kind == LOCAL])
    assert spikes.min() >= 2 and spikes.max() <= 4
    assert local.min() >= 1 and local.max() <= 2
    assert (off[d.y == 1] > 0).any() and (off[d.y == 1] < 0).any()
    assert (off[d.y == 0] == 0).all()
    dur = d.params["anomaly_duration"][d.kind == LOCAL]
    assert dur.min() >= 0.05 and dur.max() <= 0.2
    # X minus the offset is nuisance + noise: the offset is added exactly on the mask.
    residual = d.X - d.mask * off[:, None, None].astype(np.float32) - d.nuisance
    z = residual / d.noise_std
    assert abs(z.mean()) < 0.01 and abs(z.std() - 1) < 0.01


def test_bernoulli_rate_option() -> None:
    d = generate(1, 20000, seed=5, exact_rate=False)
    assert abs(d.y.mean() - 0.1) < 0.01
    assert abs((d.kind == SPIKE).sum() / d.y.sum() - 0.5) < 0.05


def test_parameters_within_their_group_ranges() -> None:
    d = generate(8, 2000, seed=2)
    for c, group in enumerate(d.meta["groups"]):
        ranges = GROUPS[group]
        for name, values in d.params.items():
            if values.ndim == 2:
                lo, hi = getattr(ranges, name)
                assert lo <= values[:, c].min() and values[:, c].max() <= hi, (name, group)


@pytest.mark.parametrize(("number", "odds"), [(5, None), (6, "hetero"), (8, "hetero")])
def test_channel_frequencies_follow_the_odds(number: int, odds: str | None) -> None:
    d = generate(number, 40000, seed=11)  # 2,000 spikes and 2,000 local deviations
    for kind, p in ((SPIKE, P_SPIKE), (LOCAL, P_LOCAL)):
        expected_p = np.full(6, 1 / 6) if odds is None else np.array(p)
        counts = np.bincount(d.channel[d.kind == kind], minlength=6)
        assert stats.chisquare(counts, counts.sum() * expected_p).pvalue > 1e-3
        # The test has power: the other kind's odds are rejected.
        if odds is not None:
            other = np.array(P_LOCAL if kind == SPIKE else P_SPIKE)
            assert stats.chisquare(counts, counts.sum() * other).pvalue < 1e-6


@settings(max_examples=50, deadline=None)
@given(f=st.floats(1, 25), amp=st.floats(0.2, 2), phi=st.floats(0, 2 * np.pi),
       tc=st.floats(0.4, 1.6), k_f=st.floats(0.5, 1.5))
def test_phase_continuity_at_t_change_when_k_a_is_one(
    f: float, amp: float, phi: float, tc: float, k_f: float
) -> None:
    p = [np.array([[v]]) for v in (f, amp, phi, tc, k_f, 1.0)]
    t = np.array([tc - 1e-9, tc])
    s = comp.sinusoid(t, *p)[0, :, 0]
    assert abs(s[1] - s[0]) < 1e-6
    # ... and k_A scales only the part after the change.
    p[-1] = np.array([[1.3]])
    s2 = comp.sinusoid(np.array([tc - 0.05, tc + 0.05]), *p)[0, :, 0]
    s1 = comp.sinusoid(np.array([tc - 0.05, tc + 0.05]), *p[:-1], np.array([[1.0]]))[0, :, 0]
    assert s2[0] == pytest.approx(s1[0]) and s2[1] == pytest.approx(1.3 * s1[1])


@settings(max_examples=50, deadline=None)
@given(t0=st.floats(0.4, 1.6), dt=st.floats(0.05, 0.2), psi=st.floats(0, 6.28),
       alpha=st.floats(0.2, 2), f_hf=st.floats(5, 50))
def test_burst_is_zero_outside_its_closed_support(
    t0: float, dt: float, psi: float, alpha: float, f_hf: float
) -> None:
    t = np.arange(2000) / 1000
    b = comp.hf_burst(t, *[np.array([[v]]) for v in (t0, dt, psi, alpha, f_hf)])[0, :, 0]
    outside = (t < t0) | (t > t0 + dt)
    assert (b[outside] == 0).all()
    inside = ~outside
    expected = alpha * np.sin(2 * np.pi * f_hf * t[inside] + psi)
    np.testing.assert_allclose(b[inside], expected, atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(omega=st.floats(0.01, 0.1), period=st.floats(0.1, 0.5), beta=st.floats(0.2, 2))
def test_impulses_match_the_brute_force_sum_and_vanish_off_support(
    omega: float, period: float, beta: float
) -> None:
    t = np.arange(4000) / 2000
    got = comp.impulses(t, *[np.array([[v]]) for v in (omega, period, beta)], duration=2.0)[0, :, 0]
    n_impulses = int(np.floor(2.0 / period))
    want = np.zeros_like(t)
    support = np.zeros_like(t, dtype=bool)
    for k in range(n_impulses):
        tau = t - k * period
        on = (tau >= 0) & (tau <= 3 * omega)
        want += np.where(on, beta * np.exp(-((tau / omega) ** 2)), 0)
        support |= on
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
    assert (got[~support] == 0).all()
    assert got[0] == pytest.approx(beta)  # the first impulse starts at t = 0


def test_stages_nest_under_one_seed() -> None:
    n, seed = 300, 9
    s5, s6, s7, s8 = (generate(k, n, seed, components=True) for k in (5, 6, 7, 8))
    assert np.array_equal(s5.nuisance, s6.nuisance) and np.array_equal(s5.noise_std, s6.noise_std)
    t = np.arange(200) / 100
    p7, p8 = s7.params, s8.params
    bursts = comp.hf_burst(t, p7["t_hf"], p7["dt_hf"], p7["psi"], p7["alpha_hf"], p7["f_hf"])
    np.testing.assert_allclose(s7.nuisance, s6.nuisance + bursts, atol=1e-5)
    assert (bursts != 0).any()
    impulses = comp.impulses(t, p8["omega"], p8["imp_period"], p8["beta"], 2.0)
    np.testing.assert_allclose(s8.nuisance, s7.nuisance + impulses, atol=1e-5)
    for name in ("f", "amp", "sigma", "phi", "t_change", "k_f", "k_a", "d_sigma"):
        assert np.array_equal(s5.params[name], s8.params[name])
    assert np.array_equal(s7.noise_std, s8.noise_std)
    # Stage 6 only changes which channel carries the anomaly.
    assert np.array_equal(s5.kind, s6.kind)


@pytest.mark.parametrize("number", [1, 4, 8])
def test_same_seed_is_bit_identical_and_another_seed_differs(number: int) -> None:
    a, b, c = generate(number, 1500, 4), generate(number, 1500, 4), generate(number, 1500, 5)
    for key in ("X", "y", "mask", "kind", "channel"):
        assert np.array_equal(getattr(a, key), getattr(b, key))
    assert all(np.array_equal(a.params[k], b.params[k]) for k in a.params)
    assert not np.array_equal(a.X, c.X)


def test_field_rate_clean_signal_matches_reference_rate() -> None:
    ref = generate(8, 40, seed=6, components=True)
    fine = generate(8, 40, seed=6, fs=2000, components=True)
    assert fine.X.shape == (40, 4000, 6) and fine.meta["fs"] == 2000
    np.testing.assert_allclose(fine.nuisance[:, ::20], ref.nuisance, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(fine.noise_std[:, ::20], ref.noise_std)
    # The same anomalies: a spike lasts 0.01 s (20 samples), local deviations 20x more samples.
    np.testing.assert_array_equal(fine.mask[:, ::20], ref.mask)
    lengths = fine.mask.sum(axis=(1, 2))
    assert (lengths[fine.kind == SPIKE] == 20).all()
    dur = fine.params["anomaly_duration"][fine.kind == LOCAL]
    assert (np.abs(lengths[fine.kind == LOCAL] - dur * 2000) <= 1).all()


def test_saved_file_loads_with_plain_numpy(tmp_path) -> None:  # type: ignore[no-untyped-def]
    d = generate(7, 50, seed=0, components=True)
    path = d.save(tmp_path / "s7.npz")
    with np.load(path) as f:  # no project code, no pickle
        keys = {"X", "y", "mask", "kind", "channel", "meta", "nuisance", "noise_std"}
        assert keys <= set(f.files)
        meta = json.loads(str(f["meta"]))
        assert meta["stage"] == 7 and meta["seed"] == 0 and meta["fs"] == 100
        assert meta["groups"] == ["axle", "axle", "bogie", "bogie", "body", "body"]
        assert meta["spec_version"] and set(meta["param_keys"]) <= set(f.files)
        np.testing.assert_array_equal(f["X"], d.X)
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left behind
