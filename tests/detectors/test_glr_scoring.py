"""``scoring=glr``: a reconstruction model's residual scored by the shared GLR scan."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from railwatch.detectors import create
from railwatch.detectors.registry import GLR_VARIANTS, REGISTRY, class_for
from railwatch.errors import RailwatchError
from railwatch.scoring.residual import ResidualGLR
from railwatch.synthetic import generate
from railwatch.windows import WindowSet
from support import tiny_config as tiny


@pytest.fixture(scope="module")
def data() -> tuple[WindowSet, WindowSet]:
    return generate(3, 160, seed=0), generate(3, 40, seed=1)


def test_every_reconstruction_model_has_a_glr_row() -> None:
    for name in GLR_VARIANTS:
        row = f"{name}+glr"
        assert class_for(row) is class_for(name)
        det = create(row, tiny(row))
        assert det.config.scoring == "glr" and "scoring" in det.scoring_fields  # type: ignore[attr-defined]
        with pytest.raises(RailwatchError, match=r"unknown scoring mode 'gl' for \w+; choose one "
                                                 r"of .*glr"):
            create(name, {"scoring": "gl"})
    assert not [n for n in REGISTRY if n.endswith("+glr") and n[:-4] not in GLR_VARIANTS]


def test_glr_row_is_the_same_network_scored_by_the_scan(data) -> None:  # type: ignore[no-untyped-def]
    train, test = data
    paper = create("cnn-ae", tiny("cnn-ae+glr")).fit(train.X)
    before = paper.score(test.X).channel
    switched = paper.rescored(train.X, scoring="glr")
    direct = create("cnn-ae+glr", tiny("cnn-ae+glr")).fit(train.X)
    s = switched.score(test.X, extras=True)
    np.testing.assert_array_equal(s.channel, direct.score(test.X).channel)
    assert switched.threshold_ == direct.threshold_ != paper.threshold_
    np.testing.assert_array_equal(paper.score(test.X).channel, before)  # the paper row unchanged
    # the residual is the input minus the reconstruction, in normalised units
    x = paper.normalized(test.X)
    with torch.no_grad():
        reconstruction = paper.model_(torch.from_numpy(x)).numpy()
    np.testing.assert_allclose(s.extras["residual"], x - reconstruction, atol=1e-5)
    np.testing.assert_array_equal(s.channel, ResidualGLR(seed=0).channel_scores(
        s.extras["residual"]))
    np.testing.assert_array_equal(s.point, s.channel.max(axis=2))
    np.testing.assert_array_equal(s.instance, s.point.max(axis=1))


def test_switching_to_the_scan_reuses_the_training_residual(data, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    train, test = data
    paper = create("lstm-ed", tiny("lstm-ed+glr")).fit(train.X)
    direct = create("lstm-ed+glr", tiny("lstm-ed+glr")).fit(train.X)
    network = type(paper).raw_outputs

    def no_network(self, X):  # type: ignore[no-untyped-def]
        raise AssertionError("the network ran over the training windows again")

    monkeypatch.setattr(type(paper), "raw_outputs", no_network)
    switched = paper.rescored(train.X, scoring="glr")  # the kept residual, scanned
    assert switched.threshold_ == direct.threshold_
    np.testing.assert_array_equal(switched.decision_scores_, direct.decision_scores_)
    with pytest.raises(AssertionError, match="network ran"):  # other windows: the network runs
        paper.rescored(test.X, scoring="glr")
    monkeypatch.setattr(type(paper), "raw_outputs", network)
    assert paper.rescored(test.X, scoring="glr").threshold_ != switched.threshold_
    # trained again on the same windows: the residual of the earlier network is not reused
    longer = {**tiny("lstm-ed+glr"), "epochs": tiny("lstm-ed+glr").get("epochs", 1) + 1}
    direct.config = replace(direct.config, epochs=longer["epochs"])
    assert direct.fit(train.X).threshold_ == create("lstm-ed+glr", longer).fit(train.X).threshold_


def test_mscred_residual_is_scanned_per_step(data) -> None:  # type: ignore[no-untyped-def]
    train, test = data
    det = create("mscred+glr", tiny("mscred+glr")).fit(train.X)
    s = det.score(test.X, extras=True)
    r = s.extras["residual"]  # (N, K, C): one value per 10-sample step
    assert r.shape == (40, 20, 2)
    steps = s.channel.reshape(40, 20, 10, 2)
    assert (steps == steps[:, :, :1]).all()  # each step's score covers its samples
    per_step = ResidualGLR(min_box=2, max_box=3, seed=0).channel_scores(r)
    np.testing.assert_array_equal(steps[:, :, 0], per_step)
