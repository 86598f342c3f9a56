"""The track map as one HTML file an engineer opens: offline (Bokeh's JavaScript embedded, no
tile server), ``track-map --report MAP.html``.

What it shows, top to bottom:

* the line, drawn from the passes' GNSS fixes (east and north, in metres, of the line's first
  point) or, without them, straight along the track kilometre; every reported place on it,
  coloured by its status on the work list (growing and unexplained, unexplained, an asset that
  changed or answers more than its kind, an asset that answers as its kind), and the
  register's assets as squares;
* the selected place's strength on every pass, by date (by pass where the passes carry no
  date): the report opens on the work list's first place, and a click on any place (on the
  line, on the evidence or in the table) shows its own;
* the evidence fused over the passes along the track, with the reporting level and the places;
* the work list and every other reported place as a table, each column sortable.

The report draws what ``track-map`` found (:mod:`railwatch.trackmap`): :func:`report_map`
asks the map for its places, their points on the earth and their history, :func:`write_report`
draws them.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from railwatch.atomic import atomic_path
from railwatch.trackmap.geo import plane
from railwatch.trackmap.welds import GROUP as WELD_GROUP

if TYPE_CHECKING:
    from railwatch.trackmap.folder import PassEvents
    from railwatch.trackmap.geo import Geo
    from railwatch.trackmap.maps import TrackMap
    from railwatch.trackmap.worklist import Plan

#: Colours of the places' statuses (the work list's tiers, then a normal asset).
COLOURS = {"growing, unexplained": "#d62728", "unexplained": "#ff7f0e",
           "asset: changed or worse than its kind": "#9467bd", "asset, as its kind": "#8c8c8c"}
#: The evidence curve is drawn with at most this many points (the highest of each bin kept).
EVIDENCE_POINTS = 6000


def _peaks(x: NDArray[np.float64], y: NDArray[np.float64], n: int
           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """At most ``n`` points of a curve: each bin's highest."""
    if len(x) <= n:
        return x, y
    edges = np.linspace(0, len(x), n + 1).astype(int)
    idx = np.array([a + int(np.nanargmax(y[a:b])) if np.isfinite(y[a:b]).any() else a
                    for a, b in zip(edges[:-1], edges[1:], strict=True)])
    return x[idx], y[idx]


def _when(started: str | None) -> float:
    """A pass's date as Bokeh's datetime axis counts (ms since 1970, UTC); NaN if undated."""
    if not started:
        return math.nan
    from railwatch.trackmap.folder import started_time

    return float(started_time(started).value / 1e6)


def report_map(path: str | os.PathLike[str], made: TrackMap, done: Plan,
               passes: list[PassEvents], geo: Geo, summary: str, reach_m: float) -> Path:
    """The report of a map (``made``) with all ``track-map`` said of it (``done``), its
    ``passes``, its places on the earth (``geo``, :func:`railwatch.trackmap.geo.locate`), the
    closing line as its ``summary``; each place's history within ``reach_m`` of it."""
    from railwatch import trackmap as tm

    rows = tm.geo.features(made, done)
    history = (tm.trends.history(made.reported, passes, made.fused, reach_m)
               if made.fused is not None else [])
    on_line = done.labelled.on_line if done.labelled is not None else []
    centres = np.array([(a.start_m + a.end_m) / 2 for a in on_line], dtype=float)
    alat, alon, _ = tm.geo.at_positions(made, passes, centres)
    assets = [{"id": a.id, "kind": a.kind, "km": x / 1e3, "lat": la, "lon": lo}
              for a, x, la, lo in zip(on_line, centres, alat, alon, strict=True)]
    return write_report(path, f"railwatch track map: {Path(path).stem}", summary, rows,
                        geo.of([r["rank"] for r in rows]), geo.line,
                        tm.covered_range(passes), history,
                        (made.fused.grid, made.fused.evidence) if made.fused is not None
                        else None, made.level, assets,
                        (made.fused.welds.grid, made.fused.welds.top, made.fused.welds.level(0.1))
                        if made.fused is not None and made.fused.welds is not None else None,
                        tm.trends.unit(made.fused) if made.fused is not None else "score")


def write_report(path: str | os.PathLike[str], title: str, summary: str,
                 places: list[dict[str, Any]], where: tuple[NDArray[np.float64],
                                                            NDArray[np.float64]],
                 line: NDArray[np.float64], covered: tuple[float, float],
                 history: list[dict[str, Any]], evidence: tuple[NDArray[np.float64],
                                                                NDArray[np.float64]] | None,
                 level: float | None, assets: Sequence[dict[str, Any]] = (),
                 welds: tuple[NDArray[np.float64], NDArray[np.float64], float] | None = None,
                 measure: str = "score") -> Path:
    """Write the report (module docstring). ``places``: every reported place's fields, work
    list first (:func:`railwatch.trackmap.geo.features`); ``where``: their latitude and
    longitude (NaN: unknown); ``line``: (k, 2) latitude, longitude (empty: no GNSS);
    ``covered``: the stretch mapped (m); ``history``: each place's strength per pass
    (:func:`railwatch.trackmap.trends.history`); ``evidence``: the fused evidence along the
    map (positions m, values) and the reporting ``level``, None for a votes map; ``assets``:
    the register's assets on the line (id, kind, km, lat, lon), drawn as grey squares;
    ``welds``: the map's weld layer (positions m, fused z, its level at 0.1 places per km),
    None without one; ``measure``: what a strength is (the history's axis)."""
    from bokeh.embed import file_html
    from bokeh.layouts import column, row
    from bokeh.models import (
        ColumnDataSource,
        CustomJS,
        DataTable,
        Div,
        HoverTool,
        NumberFormatter,
        Span,
        TableColumn,
        TapTool,
    )
    from bokeh.plotting import figure
    from bokeh.resources import INLINE

    lat, lon = (np.asarray(a, dtype=float) for a in where)
    on_earth = len(line) >= 2  # a place the fixes do not reach is left off the plan only
    km = np.array([p["position_m"] / 1e3 for p in places], dtype=float)
    if on_earth:
        lat0, lon0 = float(line[0, 0]), float(line[0, 1])
        x, y = plane(lat, lon, lat0, lon0)
        lx, ly = plane(line[:, 0], line[:, 1], lat0, lon0)
    else:
        x, y = km, np.zeros(len(km))
        lx, ly = np.array(covered, dtype=float) / 1e3, np.zeros(2)

    def label(p: dict[str, Any]) -> str:
        what = f"{p['asset_kind']} {p['asset']}" if p["asset_kind"] else "place"
        return (f"#{p['priority']} " if p["priority"] else "") + f"{what} at km {p['track_km']:.3f}"

    source = ColumnDataSource({
        "x": x, "y": y, "km": km, "rank": [p["rank"] for p in places],
        "priority": [p["priority"] if p["priority"] else math.nan for p in places],
        "status": [p["status"] for p in places],
        "colour": [COLOURS.get(p["status"], "#1f77b4") for p in places],
        "what": [f"{p['asset_kind']} {p['asset']}" if p["asset_kind"] else "" for p in places],
        "evidence": [p["evidence"] if p["evidence"] is not None else math.nan for p in places],
        # the evidence panel draws the event layer's places: a weld place's evidence is its own
        # layer's chance, drawn in the weld panel at its z
        "on_evidence": [p["evidence"] if p["evidence"] is not None
                        and p.get("group") != WELD_GROUP else math.nan for p in places],
        "weld_z": [p["weld_z"] if p["weld_z"] is not None else math.nan for p in places],
        "growth": [p["growth"] if p["growth"] is not None else math.nan for p in places],
        "interval": [f"{p['growth_low']:.2f}-{p['growth_high']:.2f}"
                     if p["growth_low"] is not None and p["growth_high"] is not None else ""
                     for p in places],
        "seen": [f"{p['passes_seen']} of {p['passes_covered']}" for p in places],
        "why": [p["why"] for p in places], "label": [label(p) for p in places],
        "lat": lat, "lon": lon})
    dated = any(h["started"] for h in history)
    hx = [_when(h["started"]) if dated else float(h["order"]) for h in history]
    every = ColumnDataSource({"rank": [h["rank"] for h in history], "x": hx,
                              "strength": [h["strength"] for h in history],
                              "pass": [h["pass"] for h in history]})
    first = 0 if places else None
    shown = [k for k, h in enumerate(history) if first is not None
             and h["rank"] == places[first]["rank"]]
    hist = ColumnDataSource({"x": [hx[k] for k in shown],
                             "strength": [history[k]["strength"] for k in shown],
                             "pass": [history[k]["pass"] for k in shown]})
    if first is not None:
        source.selected.indices = [first]

    tips = [("", "@label"), ("status", "@status"), ("evidence", "@evidence{0.0}"),
            ("weld test", "z = @weld_z{0.0}"),
            ("growth", "x@growth{0.00} (@interval)"), ("seen on", "@seen passes"),
            ("why", "@why")]
    plan = figure(title="the line, from the passes' GNSS fixes (m east and north)" if on_earth
                  else "the line by track km (the recordings carry no GNSS fixes)",
                  width=760, height=420 if on_earth else 200, match_aspect=on_earth,
                  tools="pan,wheel_zoom,box_zoom,reset,save", name="line",
                  x_axis_label="east (m)" if on_earth else "track km",
                  y_axis_label="north (m)" if on_earth else None)
    plan.line(lx, ly, color="#444444", line_width=2)
    if assets:
        akm = np.array([a["km"] for a in assets], dtype=float)
        if on_earth:
            ax, ay = plane(np.array([a["lat"] for a in assets], dtype=float),
                            np.array([a["lon"] for a in assets], dtype=float), lat0, lon0)
        else:
            ax, ay = akm, np.zeros(len(assets))
        known = ColumnDataSource({"x": ax, "y": ay, "km": akm, "id": [a["id"] for a in assets],
                                  "kind": [a["kind"] for a in assets]})
        ticks = plan.scatter("x", "y", source=known, marker="square", size=7,
                             fill_color="white", line_color="#666666",
                             legend_label="asset in the register", name="assets")
        plan.add_tools(HoverTool(renderers=[ticks], tooltips=[("asset", "@kind @id"),
                                                              ("track km", "@km{0.000}")]))
    dots = plan.scatter("x", "y", source=source, size=11, fill_color="colour",
                        line_color="black", legend_field="status", name="places",
                        selection_line_width=3, nonselection_fill_alpha=0.7,
                        nonselection_line_alpha=0.7)
    plan.add_tools(TapTool(renderers=[dots]), HoverTool(renderers=[dots], tooltips=tips))
    plan.legend.location = "top_left"
    plan.legend.label_text_font_size = "9pt"
    if not on_earth:
        plan.yaxis.visible = False

    chart = figure(title="strength per pass" + (" by date" if dated else " (undated passes, "
                                                                         "in their order)"),
                   width=520, height=420 if on_earth else 200,
                   x_axis_type="datetime" if dated else "linear", name="history",
                   x_axis_label="date" if dated else "pass", y_axis_label=measure,
                   tools="pan,wheel_zoom,reset,save")
    chart.line("x", "strength", source=hist, color="#d62728")
    chart.scatter("x", "strength", source=hist, size=7, color="#d62728")
    chart.add_tools(HoverTool(tooltips=[("pass", "@pass"), ("strength", "@strength{0.00}")]))
    heading = Div(text=f"<b>{label(places[first])}</b>" if first is not None
                  else "no reported place", name="heading")

    parts: list[Any] = []
    if evidence is not None:
        ex, ey = _peaks(np.asarray(evidence[0], float) / 1e3, np.asarray(evidence[1], float),
                        EVIDENCE_POINTS)
        along = figure(title="evidence fused over the passes", width=1300, height=230,
                       x_axis_label="track km", y_axis_label="evidence (−log10 p)",
                       tools="xpan,xwheel_zoom,reset,save", name="evidence")
        along.line(ex, ey, color="#555555", line_width=1)
        if level is not None and math.isfinite(level):
            along.add_layout(Span(location=level, dimension="width", line_color="#d62728",
                                  line_dash="dashed"))
        marks = along.scatter("km", "on_evidence", source=source, size=9, fill_color="colour",
                              line_color="black", selection_line_width=3,
                              nonselection_fill_alpha=0.7, nonselection_line_alpha=0.7)
        along.add_tools(TapTool(renderers=[marks]), HoverTool(renderers=[marks], tooltips=tips))
        parts.append(along)
    if welds is not None:
        wx, wy = _peaks(np.asarray(welds[0], float) / 1e3,
                        np.nan_to_num(np.asarray(welds[1], float), nan=0.0), EVIDENCE_POINTS)
        shared = {"x_range": parts[-1].x_range} if parts else {}
        dips = figure(title="weld test fused over the passes (the rails' height, measured by "
                            "the axle boxes)", width=1300, height=200, x_axis_label="track km",
                      y_axis_label="z", tools="xpan,xwheel_zoom,reset,save", name="welds",
                      y_range=(0.0, 4 * welds[2]), **shared)
        dips.line(wx, wy, color="#555555", line_width=1)
        dips.add_layout(Span(location=welds[2], dimension="width", line_color="#d62728",
                             line_dash="dashed"))
        weld_marks = dips.scatter("km", "weld_z", source=source, size=9, fill_color="colour",
                                  line_color="black", selection_line_width=3,
                                  nonselection_fill_alpha=0.7, nonselection_line_alpha=0.7)
        dips.add_tools(TapTool(renderers=[weld_marks]),
                       HoverTool(renderers=[weld_marks], tooltips=tips))
        parts.append(dips)

    number = NumberFormatter(format="0.0")
    table = DataTable(source=source, name="worklist", width=1300, height=320,
                      sortable=True, reorderable=False, index_position=None, columns=[
                          TableColumn(field="priority", title="priority",
                                      formatter=NumberFormatter(format="0"), width=60),
                          TableColumn(field="status", title="status", width=200),
                          TableColumn(field="what", title="asset", width=140),
                          TableColumn(field="km", title="track km",
                                      formatter=NumberFormatter(format="0.000"), width=70),
                          TableColumn(field="evidence", title="evidence", formatter=number,
                                      width=70),
                          TableColumn(field="weld_z", title="weld z", formatter=number,
                                      width=60),
                          TableColumn(field="growth", title="growth ×",
                                      formatter=NumberFormatter(format="0.00"), width=70),
                          TableColumn(field="interval", title="95 %", width=80),
                          TableColumn(field="seen", title="passes seen", width=90),
                          TableColumn(field="why", title="why", width=520)])

    show = CustomJS(args={"places": source, "every": every, "hist": hist, "heading": heading},
                    code="""
const i = places.selected.indices;
if (!i.length) { return; }
const rank = places.data.rank[i[0]];
const d = every.data;
const x = [], strength = [], name = [];
for (let k = 0; k < d.rank.length; k++) {
  if (d.rank[k] === rank) { x.push(d.x[k]); strength.push(d.strength[k]); name.push(d.pass[k]); }
}
hist.data = {x: x, strength: strength, pass: name};
heading.text = "<b>" + places.data.label[i[0]] + "</b>";
""")
    source.selected.js_on_change("indices", show)

    head = Div(text=f"<h2>{title}</h2><p>{summary}</p><p style='color:#555'>Click a place "
                    "(on the line, on the evidence or in the table) for its strength on every "
                    "pass; sort the table by any column.</p>", width=1300)
    page = column(head, row(plan, column(heading, chart)), *parts,
                  Div(text="<h3>Work list, then the other reported places</h3>"), table)
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(file_html(page, resources=INLINE, title=title), encoding="utf-8")
    return path
