"""The paper's Tables I and II and the localisation table, from benchmark records.

Records are the per-cell dictionaries of ``results.json`` (stage, detector, seed, metrics, timings).
Each table is built once as rows of cells (:class:`Table`), then written as Markdown, CSV or HTML.
"""

from __future__ import annotations

import csv
import io
import math
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field
from html import escape
from typing import Any

import numpy as np

from railwatch.detectors import registry

#: The paper's Table I (AUC per stage). Columns: the paper's five models, mapped to registry
#: names. The paper does not say which scoring variant its own column used; we set it beside
#: ``aft-attention``, its headline variant.
PAPER_TABLE1: dict[str, tuple[float, ...]] = {
    "lstm-ed": (0.956, 0.942, 0.911, 0.907, 0.859, 0.854, 0.693, 0.667),
    "cnn-ae": (0.960, 0.921, 0.905, 0.883, 0.855, 0.857, 0.732, 0.684),
    "mscred": (0.977, 0.969, 0.960, 0.944, 0.917, 0.920, 0.782, 0.773),
    "anomaly-transformer": (0.989, 0.989, 0.988, 0.987, 0.985, 0.981, 0.864, 0.851),
    "aft-attention": (0.992, 0.988, 0.989, 0.982, 0.979, 0.971, 0.844, 0.815),
}
#: The paper's Table II: inference seconds on 3,000 test windows at batch 32, stages 1, 3, 5.
PAPER_TABLE2: dict[str, dict[int, float]] = {
    "lstm-ed": {1: 156.7, 3: 306.8, 5: 941.5},
    "cnn-ae": {1: 67.1, 3: 139.7, 5: 403.9},
    "mscred": {1: 169.7, 3: 584.8, 5: 2320.3},
    "anomaly-transformer": {1: 142.3, 3: 264.2, 5: 673.5},
    "aft-attention": {1: 100.5, 3: 177.2, 5: 502.5},
}
STAGE_NAMES = {1: "Baseline", 2: "Speed variation", 3: "2 channels", 4: "Larger noise",
               5: "6 channels", 6: "Heterogeneous odds", 7: "HF local noise",
               8: "Periodic impulses"}
#: A drop from one stage to the next larger than this is marked, as the paper's red entries.
DROP_MARK = 0.02


@dataclass
class Table:
    title: str
    header: list[str]
    rows: list[list[str]] = field(default_factory=list)
    note: str = ""

    def markdown(self) -> str:
        lines = [f"### {self.title}", "", "| " + " | ".join(self.header) + " |",
                 "|" + "---|" * len(self.header)]
        lines += ["| " + " | ".join(r) + " |" for r in self.rows]
        if self.note:
            lines += ["", self.note]
        return "\n".join(lines) + "\n"

    def html(self) -> str:
        head = "".join(f"<th>{escape(h)}</th>" for h in self.header)
        body = "".join(
            "<tr>" + "".join(f"<td>{_html_cell(c)}</td>" for c in r) + "</tr>" for r in self.rows
        )
        note = f"<p class='note'>{escape(self.note)}</p>" if self.note else ""
        return (f"<h3>{escape(self.title)}</h3><table><thead><tr>{head}</tr></thead>"
                f"<tbody>{body}</tbody></table>{note}")


def _html_cell(text: str) -> str:
    # **x** marks a drop beyond DROP_MARK, as the paper's red entries.
    if text.startswith("**") and text.endswith("**"):
        return f"<span class='drop'>{escape(text[2:-2])}</span>"
    return escape(text)


def aggregate(records: Iterable[dict[str, Any]], metric: str) -> dict[tuple[int, str], list[float]]:
    """(stage, detector) -> the metric's values over seeds (NaN and None dropped)."""
    out: dict[tuple[int, str], list[float]] = defaultdict(list)
    for r in records:
        v = r.get(metric)
        if v is not None and not (isinstance(v, float) and math.isnan(v)):
            out[(int(r["stage"]), str(r["detector"]))].append(float(v))
    return out


def mean_std(values: list[float]) -> tuple[float, float]:
    if not values:
        return math.nan, math.nan
    return float(np.mean(values)), float(np.std(values)) if len(values) > 1 else 0.0


def fmt(mean: float, std: float, n: int, digits: int = 3) -> str:
    if math.isnan(mean):
        return "–"
    return f"{mean:.{digits}f} ± {std:.{digits}f}" if n > 1 else f"{mean:.{digits}f}"


def auc_table(
    records: list[dict[str, Any]], metric: str, stages: list[int], detectors: list[str],
    with_paper: bool,
) -> Table:
    """Stage rows, detector columns, mean ± std over seeds, with each stage's drop."""
    agg = aggregate(records, metric)
    header = ["stage", ""] + [d + (" (ceiling)" if registry.role(d) == "ceiling" else "")
                              for d in detectors]
    table = Table(title=f"{metric} per stage", header=header)
    previous: dict[str, float] = {}
    for s in stages:
        row = [str(s), STAGE_NAMES[s]]
        drops = ["", "(drop)"]
        for d in detectors:
            vals = agg.get((s, d), [])
            m, sd = mean_std(vals)
            cell = fmt(m, sd, len(vals))
            if with_paper and d in PAPER_TABLE1:
                cell += f" (paper {PAPER_TABLE1[d][s - 1]:.3f})"
            row.append(cell)
            if d in previous and not math.isnan(m) and not math.isnan(previous[d]):
                drop = m - previous[d]
                text = f"({drop:+.3f})"
                drops.append(f"**{text}**" if drop < -DROP_MARK else text)
            else:
                drops.append("")
            previous[d] = m
        table.rows.append(row)
        if any(drops[2:]):
            table.rows.append(drops)
    table.note = (f"Mean ± std over seeds. (drop): change from the previous stage in this run; "
                  f"**bold** marks a drop greater than {DROP_MARK}, as the paper's red entries.")
    return table


def paper_difference_table(
    records: list[dict[str, Any]], stages: list[int], detectors: list[str]
) -> Table:
    """Ours minus the paper's Table I, for the paper's models."""
    agg = aggregate(records, "auc_instance")
    cols = [d for d in detectors if d in PAPER_TABLE1]
    top = registry.ceiling(detectors)
    table = Table(title="auc_instance: ours − paper", header=["stage", *cols]
                  + ([f"{top} ceiling − paper's best"] if top is not None else []))
    for s in stages:
        row = [str(s)]
        for d in cols:
            m, _ = mean_std(agg.get((s, d), []))
            row.append("–" if math.isnan(m) else f"{m - PAPER_TABLE1[d][s - 1]:+.3f}")
        if top is not None:
            m, _ = mean_std(agg.get((s, top), []))
            best = max(v[s - 1] for v in PAPER_TABLE1.values())
            row.append("–" if math.isnan(m) else f"{m - best:+.3f}")
        table.rows.append(row)
    table.note = ("Negative: we measure less than the paper. The last column compares the "
                  "paper's best model with the oracle ceiling of our instance-level AUC; a "
                  "negative value there means the paper reports more than the data allow.")
    return table


def references(detectors: list[str]) -> list[str]:
    """The detectors that are not learned models (``registry.ROLES``): the ceiling first, then
    the classical references."""
    return sorted((d for d in detectors if registry.role(d) != "learned"),
                  key=lambda d: -registry.ROLES.index(registry.role(d)))


def paper_gap_table(
    records: list[dict[str, Any]], stages: list[int], detectors: list[str]
) -> Table:
    """Per stage: the paper's best model, our best learned detector, the references."""
    agg = aggregate(records, "auc_instance")
    refs = references(detectors)
    learned = [d for d in detectors if d not in refs]
    table = Table(title="Where we stand: the paper's best against ours (auc_instance)",
                  header=["stage", "paper's best", "our best learned detector", "ours − paper",
                          *refs])
    for s in stages:
        name, value = max(PAPER_TABLE1.items(), key=lambda kv: kv[1][s - 1])
        paper = value[s - 1]
        ours = [(mean_std(agg[(s, d)])[0], d) for d in learned if agg.get((s, d))]
        row = [f"{s} {STAGE_NAMES[s].lower()}", f"{paper:.3f} ({name})"]
        if ours:
            m, d = max(ours)
            row += [f"{m:.3f} ({d})", f"{m - paper:+.3f}"]
        else:
            row += ["–", "–"]
        row += [fmt(*mean_std(agg.get((s, d), [])), 1) for d in refs]
        table.rows.append(row)
    table.note = ("Learned detectors only in the third column; the oracle is the ceiling of "
                  "the stage, the matched filter what a training-light classical method gets.")
    return table


def timing_table(records: list[dict[str, Any]], detectors: list[str], env: str) -> Table:
    """The paper's Table II layout: inference seconds at the 1-, 2- and 6-channel stages."""
    agg = aggregate(records, "score_s")
    n_test = {int(r["stage"]): int(r["n_test"]) for r in records}
    table = Table(title="Inference seconds on the test set at batch 32",
                  header=["stage", "channels", *detectors])
    for s, ch in ((1, 1), (3, 2), (5, 6)):
        if not any((s, d) in agg for d in detectors):
            continue
        row = [str(s), str(ch)]
        for d in detectors:
            m, sd = mean_std(agg.get((s, d), []))
            cell = fmt(m, sd, len(agg.get((s, d), [])), digits=2)
            if d in PAPER_TABLE2:
                cell += f" (paper {PAPER_TABLE2[d][s]:.1f})"
            row.append(cell)
        table.rows.append(row)
    sizes = ", ".join(f"stage {s}: {n:,} windows" for s, n in sorted(n_test.items())
                      if s in (1, 3, 5))
    table.note = (f"Ours: {env}; median of timed scorings after a warm-up batch ({sizes}). "
                  "The paper: 3,000 windows on unnamed hardware, so compare ratios between "
                  "models, not seconds.")
    return table


def localization_table(
    records: list[dict[str, Any]], stages: list[int], detectors: list[str]
) -> Table:
    t_agg, c_agg = aggregate(records, "loc_time"), aggregate(records, "loc_channel")
    table = Table(title="Localisation: loc_time / loc_channel",
                  header=["stage", *[d for d in detectors]])
    for s in stages:
        row = [str(s)]
        for d in detectors:
            tm, _ = mean_std(t_agg.get((s, d), []))
            cm, _ = mean_std(c_agg.get((s, d), []))
            t_txt = "–" if math.isnan(tm) else f"{tm:.2f}"
            c_txt = "–" if math.isnan(cm) else f"{cm:.2f}"
            row.append(f"{t_txt} / {c_txt}")
        table.rows.append(row)
    table.note = ("loc_time: share of anomalous test windows whose most anomalous step lies in "
                  "the true span ±2 samples. loc_channel: share whose most anomalous channel (at "
                  "that step) is the true one; – on single-channel stages.")
    return table


def table1_csv(records: list[dict[str, Any]]) -> str:
    """Long format: stage, detector, metric, mean, std, n_seeds, paper."""
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["stage", "detector", "metric", "mean", "std", "n_seeds", "paper"])
    for metric in ("auc_instance", "auc_point", "auc_paper7"):
        for (s, d), vals in sorted(aggregate(records, metric).items()):
            m, sd = mean_std(vals)
            paper = PAPER_TABLE1[d][s - 1] if metric == "auc_instance" and d in PAPER_TABLE1 \
                else ""
            w.writerow([s, d, metric, f"{m:.4f}", f"{sd:.4f}", len(vals), paper])
    return buf.getvalue()
