"""Shared test helpers."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

TINY = Path(__file__).parents[1] / "configs" / "tiny"


def tiny_config(name: str) -> dict[str, Any]:
    """The tiny config of a detector (configs/tiny/NAME.yaml), silent: trains in seconds."""
    path = TINY / f"{name}.yaml"
    values = yaml.safe_load(path.read_text()) if path.exists() else {}
    return {**(values or {}), "progress": False}
