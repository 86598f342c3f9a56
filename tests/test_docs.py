"""The docs' front door: every relative link resolves, docs/README.md reaches every page, and no
usage page grows into a lab notebook (over 300 lines; dated logs go to docs/notes/)."""

from __future__ import annotations

import os
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
LINK = re.compile(r"\]\(([^)\s]+)\)")
MAX_LINES = 300


def pages() -> list[Path]:
    return sorted([REPO / "README.md", REPO / "benchmarks" / "README.md", *DOCS.rglob("*.md")])


def links(page: Path) -> list[tuple[str, Path]]:
    """The relative links of a Markdown page: (as written, the path they point to)."""
    out = []
    for target in LINK.findall(page.read_text()):
        path = target.split("#")[0]
        if path and not re.match(r"^[a-z]+:", path):
            out.append((target, Path(os.path.normpath(page.parent / path))))
    return out


def test_every_relative_link_resolves() -> None:
    broken = [f"{p.relative_to(REPO)}: {t}" for p in pages() for t, path in links(p)
              if not path.exists()]
    assert broken == []


def test_the_docs_index_reaches_every_page() -> None:
    seen, todo = set(), [DOCS / "README.md"]
    while todo:
        page = todo.pop()
        if page in seen or page.suffix != ".md" or not page.is_file():
            continue
        seen.add(page)
        todo += [path for _, path in links(page)]
    unreached = sorted(str(p.relative_to(REPO)) for p in DOCS.rglob("*.md") if p not in seen)
    assert unreached == [], "link these from docs/README.md (or a page it links)"


def test_no_usage_page_is_over_300_lines() -> None:
    long = {str(p.relative_to(REPO)): n for p in DOCS.rglob("*.md")
            if "notes" not in p.relative_to(DOCS).parts
            and (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert long == {}, "move the experiment log into a dated docs/notes/ page"


def test_the_link_check_can_fail(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("[here](missing.md) and [there](https://example.org) and [top](#top)\n")
    assert [(t, p.exists()) for t, p in links(page)] == [("missing.md", False)]
