"""Result pages: a file written whole or not at all."""

from __future__ import annotations

from pathlib import Path

from railwatch.atomic import atomic_path


def write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_markdown(path: str | Path, lines: list[str]) -> str:
    """Write a benchmark script's result page whole or not at all (its folder created); returns
    the text, for the script to print."""
    path, text = Path(path), "\n".join(lines) + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, text)
    return text
