"""One contract test over every registered detector (small settings from configs/tiny/ where a
detector has them)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from railwatch.detectors import create, load_detector, names
from railwatch.errors import RailwatchError
from railwatch.synthetic import generate
from railwatch.windows import WindowSet
from support import TINY
from support import tiny_config as tiny


def context(d: WindowSet) -> dict[str, np.ndarray]:
    return {"nuisance": d.nuisance, "noise_std": d.noise_std}


@pytest.fixture(scope="module")
def data() -> tuple[WindowSet, WindowSet]:
    return generate(3, 160, seed=0, components=True), generate(3, 40, seed=1, components=True)


@pytest.fixture(scope="module", params=names())
def fitted(request, data):  # type: ignore[no-untyped-def]
    train, _ = data
    det = create(request.param, tiny(request.param))
    return det.fit(train.X, context(train))


def test_tiny_configs_belong_to_detectors() -> None:
    """A tiny config (configs/tiny/NAME.yaml: settings that train in seconds) is optional: a
    detector without one is tested with its defaults. Each one names a registered detector and
    holds only keys it knows."""
    found = sorted(p.stem for p in TINY.glob("*.yaml"))
    assert found, TINY
    for name in found:
        assert name in names(), f"configs/tiny/{name}.yaml names no registered detector"
        create(name, tiny(name))  # every key in it is known


def test_shapes_and_api(fitted, data) -> None:  # type: ignore[no-untyped-def]
    _, test = data
    s = fitted.score(test.X, context(test))
    n, t, c = test.X.shape
    assert s.instance.shape == (n,) and s.point.shape == (n, t) and s.channel.shape == (n, t, c)
    for a in (s.instance, s.point, s.channel):
        assert np.isfinite(a).all()
    assert np.isfinite(fitted.threshold_)
    assert set(np.unique(fitted.predict(test.X, context(test)))) <= {0, 1}
    loc = fitted.localize(test.X, context(test))
    assert loc.time_index.shape == loc.channel.shape == (n,)
    assert ((loc.time_index >= 0) & (loc.time_index < t)).all()
    assert ((loc.channel >= 0) & (loc.channel < c)).all()
    np.testing.assert_allclose(loc.time_s, loc.time_index / 100.0)


def test_deterministic_under_a_seed(fitted, data) -> None:  # type: ignore[no-untyped-def]
    train, test = data
    again = create(fitted.registry_name, tiny(fitted.registry_name)).fit(train.X, context(train))
    np.testing.assert_array_equal(again.score(test.X, context(test)).instance,
                                  fitted.score(test.X, context(test)).instance)


def test_save_load_identity(fitted, data, tmp_path) -> None:  # type: ignore[no-untyped-def]
    _, test = data
    fitted.save(tmp_path / "model")
    loaded = load_detector(tmp_path / "model")
    a, b = fitted.score(test.X, context(test)), loaded.score(test.X, context(test))
    for key in ("instance", "point", "channel"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key))
    assert loaded.threshold_ == fitted.threshold_
    assert loaded.registry_name == fitted.registry_name
    header = json.loads((tmp_path / "model" / "detector.json").read_text())
    assert header["detector"] == fitted.registry_name


def test_input_errors(fitted, data) -> None:  # type: ignore[no-untyped-def]
    _, test = data
    ctx = context(test)
    with pytest.raises(RailwatchError, match="expected 2 channels, got 1"):
        fitted.score(test.X[:, :, :1], {k: v[:, :, :1] for k, v in ctx.items()})
    bad = test.X.copy()
    bad[3, 17, 1] = np.nan
    with pytest.raises(RailwatchError, match="NaN at window 3, step 17, channel 1"):
        fitted.score(bad, ctx)
    bad[3, 17, 1] = np.inf
    with pytest.raises(RailwatchError, match="inf"):
        fitted.score(bad, ctx)
    with pytest.raises(RailwatchError, match="shape"):
        fitted.score(test.X[0], ctx)
    if fitted.fixed_length:
        with pytest.raises(RailwatchError, match="steps"):
            fitted.score(test.X[:, :150], {k: v[:, :150] for k, v in ctx.items()})


def test_unfitted_unknown_and_corrupt(tmp_path, data) -> None:  # type: ignore[no-untyped-def]
    _, test = data
    for name in names():
        with pytest.raises(RailwatchError, match="not fitted"):
            create(name, tiny(name)).score(test.X, context(test))
        with pytest.raises(RailwatchError, match="unknown config key"):
            create(name, {"no_such_key": 1})
    with pytest.raises(RailwatchError, match="unknown detector"):
        create("isolation-forest")
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "detector.json").write_text("{not json")
    with pytest.raises(RailwatchError, match="not a readable railwatch model"):
        load_detector(tmp_path / "junk")
    with pytest.raises(RailwatchError, match="no model directory"):
        load_detector(tmp_path / "missing")


def test_corrupt_weights(fitted, tmp_path) -> None:  # type: ignore[no-untyped-def]
    fitted.save(tmp_path / "m")
    weights = tmp_path / "m" / "weights.pt"
    target = weights if weights.exists() else tmp_path / "m" / "stats.npz"
    target.write_bytes(b"garbage")
    with pytest.raises(RailwatchError, match="not a readable railwatch model"):
        load_detector(tmp_path / "m")


def test_injected_spike_scores_higher(fitted, data) -> None:  # type: ignore[no-untyped-def]
    _, test = data
    normal = np.flatnonzero(test.y == 0)[:5]
    clean = test.X[normal]
    spiked = clean.copy()
    spiked[:, 100, 0] += 6.0
    ctx = {k: v[normal] for k, v in context(test).items()}
    higher = fitted.score(spiked, ctx).instance > fitted.score(clean, ctx).instance
    assert higher.all(), fitted.registry_name


def test_roles_and_variants_come_from_the_registry() -> None:
    """What a report needs to know of a row, asked of the registry rather than read off its
    name: the ceiling, the classical references, and whose network a ``+glr`` row scores."""
    from railwatch.detectors import registry

    assert registry.role("oracle") == "ceiling"
    assert registry.role("matched-filter") == "reference"
    assert {registry.role(n) for n in registry.names()} <= set(registry.ROLES)
    assert registry.role("context-glr") == registry.role("a-detector-of-my-own") == "learned"
    assert registry.ceiling(["cnn-ae", "matched-filter", "oracle"]) == "oracle"
    assert registry.ceiling(["cnn-ae"]) is None
    assert registry.variant_of("cnn-ae+glr") == "cnn-ae"
    assert registry.variant_of("cnn-ae") == "cnn-ae"
    assert all(registry.variant_of(f"{n}+glr") == n for n in registry.GLR_VARIANTS)
