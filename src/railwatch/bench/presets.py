"""Benchmark presets: the defaults live in :class:`Preset`; preset files hold overrides only."""

from __future__ import annotations

import os
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from railwatch.errors import RailwatchError
from railwatch.mapping_files import read_mapping

PRESET_DIR = Path(__file__).resolve().parents[3] / "configs" / "presets"

#: The paper's five models (the attention model in its two paper variants and their combination,
#: all three from one trained network), the reconstruction models scored by the GLR scan,
#: railwatch's own detector and the two references.
DEFAULT_DETECTORS = (
    "lstm-ed", "cnn-ae", "mscred", "anomaly-transformer", "aft-attention", "aft-reconstruction",
    "aft-combined",
    # the same five reconstruction networks, their residual scored by the shared GLR scan
    "lstm-ed+glr", "cnn-ae+glr", "mscred+glr", "anomaly-transformer+glr", "aft-reconstruction+glr",
    "context-glr", "matched-filter", "oracle",
)


@dataclass(frozen=True)
class Preset:
    """One benchmark run: which cells, how much data, and each detector's config overrides."""

    name: str = "custom"
    description: str = ""
    n_train: int = 2000  # windows, the 10 % validation split included
    n_test: int = 1000
    seeds: int = 1
    stages: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 7, 8)
    detectors: tuple[str, ...] = DEFAULT_DETECTORS
    timing_repeats: int = 3  # score_s is the median of this many timed scorings
    detector_overrides: dict[str, dict[str, Any]] = field(default_factory=dict)

    def overrides_for(self, detector: str) -> dict[str, Any]:
        return dict(self.detector_overrides.get(detector, {}))


def preset_path(name_or_file: str | os.PathLike[str]) -> Path:
    """A preset name (``smoke``, ``quick``, ``standard``) or a YAML file."""
    path = Path(name_or_file)
    if path.suffix in {".yaml", ".yml"} or path.exists():
        if not path.is_file():
            raise RailwatchError(f"no such preset file: {path}")
        return path
    candidate = PRESET_DIR / f"{name_or_file}.yaml"
    if not candidate.is_file():
        known = sorted(p.stem for p in PRESET_DIR.glob("*.yaml"))
        raise RailwatchError(f"unknown preset {name_or_file!r}: use one of {', '.join(known)} "
                             "or a YAML file")
    return candidate


def load_preset(name_or_file: str | os.PathLike[str], **overrides: Any) -> Preset:
    """Read a preset and apply command-line overrides (``None`` values are ignored)."""
    path = preset_path(name_or_file)
    values = read_mapping(path, "preset")
    values.setdefault("name", path.stem)
    values.update({k: v for k, v in overrides.items() if v is not None})
    return preset_from_dict(values, source=str(path))


def preset_from_dict(values: dict[str, Any], source: str = "preset") -> Preset:
    known = {f.name for f in fields(Preset)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise RailwatchError(f"{source}: unknown key(s) {', '.join(unknown)}; valid: "
                             f"{', '.join(sorted(known))}")
    converted: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v
                                 for k, v in values.items()}
    p = replace(Preset(), **converted)
    for key in ("n_train", "n_test", "seeds", "timing_repeats"):
        if not isinstance(getattr(p, key), int) or getattr(p, key) < 1:
            raise RailwatchError(f"{source}: {key} must be a positive integer")
    bad = [s for s in p.stages if s not in range(1, 9)]
    if bad:
        raise RailwatchError(f"{source}: stages must be 1-8, got {bad}")
    from railwatch.detectors.registry import REGISTRY, create

    unknown_det = [d for d in p.detectors if d not in REGISTRY]
    if unknown_det:
        raise RailwatchError(f"{source}: unknown detector(s) {', '.join(unknown_det)}; "
                             f"available: {', '.join(REGISTRY)}")
    for name, over in p.detector_overrides.items():
        if name not in REGISTRY:
            raise RailwatchError(f"{source}: detector_overrides names unknown detector {name}")
        create(name, over)  # validates every key and type now, not hours into the run
    return p
