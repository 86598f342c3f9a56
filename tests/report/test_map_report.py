"""The track map's HTML report (``track-map --report``), exercised in headless Chromium: it
renders offline with no console error, opens on the work list's first place, and a click on
another place, on the line or in the table, shows that place's history."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from railwatch.cli import main
from support import scan_folder

DEFECTS = np.array([800.0, 1800.0, 3300.0, 4400.0])
#: Chromium as the machine's own (Debian's package, which `make test` installs), started as
#: a test starts it: no sandbox (root in a container), nothing fetched in the background.
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
#: The plot view of a model by name, found from the page's root view (Bokeh's views).
VIEW_JS = """(name) => {
  const model = Bokeh.documents[0].get_model_by_name(name);
  const find = (v) => {
    if (v.model.id === model.id) { return v; }
    for (const c of (v.child_views || [])) { const f = find(c); if (f) { return f; } }
    return null;
  };
  return find(Bokeh.index.roots[0]);
}"""


def chromium() -> str:
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if path is None:
        if os.environ.get("CI"):
            pytest.fail("no chromium: `make test` installs Debian's chromium (apt-get install "
                        "chromium)")
        pytest.skip("no chromium on this machine (make test installs it)")
    return path


@pytest.fixture(scope="module")
def report(tmp_path_factory):  # type: ignore[no-untyped-def]
    """A dated, GNSS-located line of 8 passes: the defect at 1.8 km triples, the switch at
    3.3 km answers more than the other three switches."""
    tmp = tmp_path_factory.mktemp("report")
    rng = np.random.default_rng(4)
    xs, scores = [], []
    for j in range(8):
        x = np.arange(0, 5_000.0, 0.25) + rng.uniform(0, 0.25)
        s = rng.exponential(size=len(x))
        for k, d in enumerate(DEFECTS):
            s[np.abs(x - d) <= 0.4] += 12.0 * (1.0 + 2.0 * j / 7 if k == 1 else 1.0)
        xs.append(x)
        scores.append(s)
    (tmp / "scan").mkdir()
    scan_folder(tmp / "scan", xs, scores, DEFECTS, located=True)
    for j in range(8):  # each pass's weld test: the texture, and a weld at 2.6 km
        profile = tmp / "scan" / f"pass{j:02d}.profile.npz"
        with np.load(profile) as f:
            arrays = dict(f)
        x = np.arange(0, 5_000.0, 0.05) + rng.uniform(0, 0.05)
        z = rng.normal(0, 1, (len(x), 2)) + 2.0
        z[np.abs(x - 2600.0) < 0.3, 0] = 9.0
        np.savez(profile, **arrays, weld_position_m=x, weld_z=z.astype(np.float32))
    for j in range(8):
        info_path = tmp / "scan" / f"pass{j:02d}.scan.json"
        info = json.loads(info_path.read_text())
        info["started"] = f"2026-01-{5 + 3 * j:02d}T06:00:00Z"
        info_path.write_text(json.dumps(info))
    (tmp / "assets.csv").write_text("id,kind,position_m\nS1,switch,3300\nS2,switch,1000\n"
                                    "S3,switch,2500\nS4,switch,4000\n")
    out = tmp / "map.html"
    assert main(["-q", "track-map", "--events", str(tmp / "scan"), "--out", str(tmp / "m.csv"),
                 "--assets", str(tmp / "assets.csv"), "--report", str(out)]) == 0
    return out


def test_the_report_is_one_file(report: Path) -> None:
    import re

    html = report.read_text()
    assert "<script" in html and "Bokeh" in html
    outside = re.sub(r"(<script[^>]*>).*?(</script>)", r"\1\2", html, flags=re.S)
    assert outside.count("<script") >= 2  # Bokeh's and the page's, inline
    assert not re.search(r"<(script|link|img)\b[^>]*\b(src|href)=", outside)


def test_it_renders_offline_and_a_click_shows_a_place_history(report: Path) -> None:
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium(), args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 1500})
            problems: list[str] = []
            fetched: list[str] = []
            page.on("console", lambda m: problems.append(m.text) if m.type in (
                "error", "warning") else None)
            page.on("pageerror", lambda e: problems.append(str(e)))
            page.on("request", lambda r: fetched.append(r.url))
            page.goto(report.as_uri())
            page.wait_for_function("() => window.Bokeh && Bokeh.documents.length > 0 "
                                   "&& Bokeh.index.roots.length > 0", timeout=30_000)
            page.wait_for_timeout(300)

            def model(name: str, expr: str) -> object:
                return page.evaluate(f"() => Bokeh.documents[0].get_model_by_name('{name}')"
                                     f"{expr}")

            # The weld layer along the track, with the weld at 2.6 km a place of its own.
            assert model("welds", ".title.text").startswith("weld test")
            assert 2.6 in [round(km, 1) for km, z in zip(
                model("places", ".data_source.data.km"),  # type: ignore[call-overload]
                model("places", ".data_source.data.weld_z"), strict=True) if z and z > 8]
            # The register's four switches are drawn on the line.
            assert model("assets", ".data_source.data.id.length") == 4
            # It opens on the work list's first place: the defect that grows, with 8 passes.
            assert "#1 place at km 1.80" in str(model("heading", ".text"))
            assert model("history", ".renderers[0].data_source.data.x.length") == 8
            # A click on the line's unexplained place at 4.4 km shows its own.
            x, y = page.evaluate(f"""() => {{
              const view = ({VIEW_JS})('line');
              const src = Bokeh.documents[0].get_model_by_name('places').data_source;
              const i = src.data.km.findIndex((k) => Math.abs(k - 4.4) < 0.01);
              const r = view.canvas_view.el.getBoundingClientRect();
              return [r.left + view.frame.x_scale.compute(src.data.x[i]),
                      r.top + view.frame.y_scale.compute(src.data.y[i])];
            }}""")
            page.mouse.click(x, y)
            page.wait_for_function("() => Bokeh.documents[0].get_model_by_name('heading')"
                                   ".text.includes('place at km 4.40')", timeout=5_000)
            strengths = model("history", ".renderers[0].data_source.data.strength")
            assert isinstance(strengths, list) and len(strengths) == 8
            assert max(strengths) < 2 * min(strengths)  # a stable place
            # A click on the table's row of the switch shows the switch's.
            page.get_by_text("switch S1", exact=True).click()
            page.wait_for_function("() => Bokeh.documents[0].get_model_by_name('heading')"
                                   ".text.includes('switch S1')", timeout=5_000)
            assert not problems, problems
            assert all(u.startswith(("file:", "data:", "blob:")) for u in fetched), fetched
        finally:
            browser.close()
