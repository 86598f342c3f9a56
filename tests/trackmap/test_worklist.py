"""The work list: growing unexplained places first, then unexplained ones, then assets that
changed or answer more than their kind; a normal asset is not on it."""

from __future__ import annotations

import csv
import math
from dataclasses import replace
from pathlib import Path

from railwatch import trackmap as tm
from railwatch.trackmap.assets import Asset, Response
from railwatch.trackmap.worklist import FIELDS, worklist, write_worklist

PLACE = tm.Location(rank=0, position_m=0.0, start_m=0.0, end_m=0.0, evidence=5.0,
                    false_per_km=0.01, passes_seen=5, passes_covered=5, share=1.0,
                    confidence=0.6, median_score=9.0, channel="a", group="g", kind_guess="",
                    first_seen="p1", last_seen="p5")


def place(rank: int, evidence: float, asset: str = "unexplained", kind: str = "",
          growing: str = "no", growth: float = 1.0) -> tm.Location:
    return replace(PLACE, rank=rank, position_m=100.0 * rank, evidence=evidence, asset=asset,
                   asset_kind=kind, growing=growing, growth=growth, growth_low=growth / 2,
                   growth_high=growth * 2, trend_p=0.001 if growing == "yes" else 0.5)


def test_the_order_and_who_is_left_off(tmp_path: Path) -> None:
    reported = [place(1, 20.0, "S1", "switch"),  # a normal switch: not on the list
                place(2, 15.0), place(3, 9.0, growing="yes", growth=2.0),
                place(4, 12.0, "J1", "insulated joint"),  # worse than its kind
                place(5, 11.0, "S2", "switch", growing="yes", growth=1.8),
                place(6, 18.0)]
    joint = Response(Asset("J1", "insulated joint", 400.0, 400.0), 5, 300.0, 4.2, True)
    items = worklist(reported, [joint])
    assert [it.place.rank for it in items] == [3, 6, 2, 4, 5]
    assert [it.tier for it in items] == [1, 2, 2, 3, 3]
    assert "grows x2.00" in items[0].why
    assert "4.2 spreads above the other insulated joints" in items[3].why
    out = write_worklist(tmp_path / "w.csv", items)
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == list(FIELDS) and [r["priority"] for r in rows] == list("12345")
    assert rows[3]["what"] == "insulated joint J1" and rows[1]["what"] == "unexplained"


def test_without_a_register_or_dates_it_is_the_map_by_evidence() -> None:
    reported = [replace(place(1, 7.0), asset="", growing="", growth=math.nan),
                replace(place(2, 9.0), asset="", growing="", growth=math.nan)]
    items = worklist(reported)
    assert [it.place.rank for it in items] == [2, 1] and {it.tier for it in items} == {2}
