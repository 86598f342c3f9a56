"""The benchmark's parts below the command line: the grid's cells, what makes a cell reusable,
the side arrays a detector is given, and the report's attention example chosen by a tag."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from railwatch.bench.cell import Cell, cells, dataset, fingerprint, side_arrays
from railwatch.bench.grid import attention_example
from railwatch.bench.presets import Preset
from railwatch.bench.store import ResultStore
from railwatch.detectors import create
from railwatch.synthetic import generate

PRESET = Preset(n_train=60, n_test=40, seeds=2, stages=(1, 3), detectors=("cnn-ae", "oracle"))


def test_cells_are_stage_major() -> None:
    assert [c.key for c in cells(PRESET)[:4]] == [
        "stage1-cnn-ae-seed0", "stage1-oracle-seed0", "stage1-cnn-ae-seed1", "stage1-oracle-seed1"]
    assert len(cells(PRESET)) == 2 * 2 * 2


def test_fingerprint_follows_sizes_and_overrides() -> None:
    cell = Cell(1, "cnn-ae", 0)
    other = Preset(**{**PRESET.__dict__, "detector_overrides": {"cnn-ae": {"epochs": 1}}})
    assert fingerprint(PRESET, cell) == fingerprint(Preset(**PRESET.__dict__), cell)
    assert fingerprint(other, cell) != fingerprint(PRESET, cell)
    assert fingerprint(other, Cell(1, "oracle", 0)) == fingerprint(PRESET, Cell(1, "oracle", 0))
    assert fingerprint(Preset(**{**PRESET.__dict__, "n_train": 61}), cell) != \
        fingerprint(PRESET, cell)


def test_side_arrays_are_what_the_detector_needs() -> None:
    data = generate(1, 10, 0, components=True)
    given = side_arrays(create("oracle"), data)
    assert given is not None and set(given) == {"nuisance", "noise_std"}
    assert given["nuisance"] is data.nuisance
    assert side_arrays(create("cnn-ae"), data) is None


def test_report_maps_tag() -> None:
    assert create("aft-attention").report_maps
    assert not create("aft-reconstruction").report_maps
    assert not create("aft-combined").report_maps
    assert not create("cnn-ae").report_maps


def test_attention_example_from_the_first_cell_with_maps(tmp_path: Path) -> None:
    store = ResultStore(tmp_path)
    seed0 = [Cell(1, "cnn-ae", 0), Cell(1, "aft-attention", 0)]
    test = dataset(store.cache, 1, 0, PRESET.n_test, "test")
    assert test.y is not None and test.kind is not None
    index = np.flatnonzero(test.y)[:4]
    plain = {"instance": np.zeros(40), "kind": test.kind, "example_index": index,
             "example_point": np.zeros((len(index), 200))}
    arrays = {(1, "cnn-ae"): plain, (1, "aft-attention"): plain}
    assert attention_example(PRESET, store, seed0, arrays) is None
    maps = np.random.default_rng(0).random((len(index), 1, 2, 25, 25))  # (n, C, heads, L, L)
    arrays[(1, "aft-attention")] = {**plain, "extra_attention_0": maps, "extra_attention_1": maps}
    example = attention_example(PRESET, store, seed0, arrays)
    assert example is not None and example.attention.shape == (25, 25)
    kinds = test.kind[index]
    j = int(np.argmax(kinds == 2)) if (kinds == 2).any() else 0
    np.testing.assert_allclose(example.attention, maps[j, 0].mean(axis=0))
    assert example.title.startswith(f"stage 1, test window {index[j]}: ")
