"""The report's tables from benchmark records: means over seeds, drops, the paper's values."""

from __future__ import annotations

from railwatch.report import tables as T


def records() -> list[dict]:  # type: ignore[type-arg]
    out = []
    for seed, shift in ((0, 0.0), (1, 0.02)):
        out += [{"stage": 1, "detector": "cnn-ae", "seed": seed, "auc_instance": 0.90 + shift},
                {"stage": 2, "detector": "cnn-ae", "seed": seed, "auc_instance": 0.80 + shift},
                {"stage": 1, "detector": "oracle", "seed": seed, "auc_instance": 0.99},
                {"stage": 2, "detector": "oracle", "seed": seed, "auc_instance": None}]
    return out


def test_aggregate_drops_missing_values() -> None:
    agg = T.aggregate(records(), "auc_instance")
    assert agg[(1, "cnn-ae")] == [0.90, 0.92] and (2, "oracle") not in agg


def test_auc_table_means_drops_and_paper() -> None:
    table = T.auc_table(records(), "auc_instance", [1, 2], ["cnn-ae", "oracle"], with_paper=True)
    assert table.header == ["stage", "", "cnn-ae", "oracle (ceiling)"]
    assert table.rows[0] == ["1", "Baseline", "0.910 ± 0.010 (paper 0.960)", "0.990 ± 0.000"]
    assert table.rows[1] == ["2", "Speed variation", "0.810 ± 0.010 (paper 0.921)", "–"]
    assert table.rows[2] == ["", "(drop)", "**(-0.100)**", ""]  # bold: beyond DROP_MARK
    text = table.markdown()
    assert text.startswith("### auc_instance per stage\n") and "| 1 | Baseline |" in text
    assert "<span class='drop'>(-0.100)</span>" in table.html()


def test_table1_csv_has_a_row_per_cell() -> None:
    lines = T.table1_csv(records()).strip().splitlines()
    assert len(lines) == 1 + 3  # header, then the (stage, detector) pairs with values
