"""Reading the small key: value files users write (configs, presets, recording layouts)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

import yaml

from railwatch.errors import RailwatchError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


def read_mapping(path: str | os.PathLike[str], what: str) -> dict[str, Any]:
    """The key: value pairs of a TOML (``.toml``), JSON (``.json``) or YAML (anything else) file;
    an empty file is ``{}``. Errors are one line naming ``what`` the file is (config, layout...).

    >>> import tempfile
    >>> p = Path(tempfile.mkdtemp()) / "c.yaml"
    >>> _ = p.write_text("epochs: 5")
    >>> read_mapping(p, "config")
    {'epochs': 5}
    """
    path = Path(path)
    if not path.is_file():
        raise RailwatchError(f"no such {what} file: {path}")
    text = path.read_text()
    try:
        if path.suffix == ".toml":
            data: Any = tomllib.loads(text)
        elif path.suffix == ".json":
            data = json.loads(text)
        else:
            data = yaml.safe_load(text)
    except (tomllib.TOMLDecodeError, yaml.YAMLError, json.JSONDecodeError) as e:
        raise RailwatchError(f"cannot parse {what} {path}: {' '.join(str(e).split())[:160]}") \
            from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise RailwatchError(f"{path} must hold key: value pairs, not {type(data).__name__}")
    return data
