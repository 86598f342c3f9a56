"""The detectors by name: the names ``railwatch train --detector`` takes, and the loading of a
saved model folder by the name in its header.

An entry is a class plus config overrides, so that variants of one class (the attention model's
scoring modes) are rows of their own without a class each. Classes are imported on first use, so
that naming, creating or listing detectors does not import torch until a deep one is used.
Adding a detector: one file in this folder, one entry here (``docs/architecture.md``).
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from railwatch.detectors import model_folder
from railwatch.detectors.api import GLR_SCORING, Detector, config_from_dict
from railwatch.errors import RailwatchError, naming, one_line
from railwatch.scoring import GLR_SUFFIX

#: What a detector is to a report: a ``learned`` model, a classical ``reference`` that learns no
#: network, or the ``ceiling``, which knows the generator's truth (the benchmark's upper bound).
ROLES = ("learned", "reference", "ceiling")


@dataclass(frozen=True)
class Entry:
    target: str  # "module:Class"
    description: str
    overrides: Mapping[str, Any] = field(default_factory=dict)
    role: str = "learned"  # one of ROLES
    variant_of: str = ""  # a row that scores another entry's trained network another way


REGISTRY: dict[str, Entry] = {
    "lstm-ed": Entry("railwatch.detectors.lstm_ed:LSTMEncoderDecoder",
                     "LSTM encoder-decoder (Malhotra et al. 2016), reverse-order decoding, "
                     "Mahalanobis error score"),
    "cnn-ae": Entry("railwatch.detectors.cnn_ae:CNNAutoencoder",
                    "1-D convolutional autoencoder, standardised squared reconstruction error"),
    "mscred": Entry("railwatch.detectors.mscred:MSCRED",
                    "MSCRED (Zhang et al. 2019): signature matrices, attention ConvLSTM, "
                    "broken-entry count"),
    "anomaly-transformer": Entry("railwatch.detectors.anomaly_transformer:AnomalyTransformer",
                                 "Anomaly Transformer (Xu et al. 2022), official mathematics: "
                                 "association discrepancy x reconstruction error"),
    "aft-attention": Entry("railwatch.detectors.attention_transformer:AttentionFocusedTransformer",
                           "the paper's Attention-Focused Transformer, scored by how its "
                           "attention deviates from training (the paper's contribution)",
                           {"scoring": "attention"}),
    "aft-reconstruction": Entry(
        "railwatch.detectors.attention_transformer:AttentionFocusedTransformer",
        "the paper's Attention-Focused Transformer, scored by reconstruction error",
        {"scoring": "reconstruction"}),
    "aft-combined": Entry(
        "railwatch.detectors.attention_transformer:AttentionFocusedTransformer",
        "the paper's Attention-Focused Transformer, attention and reconstruction scores combined",
        {"scoring": "combined"}),
    "context-glr": Entry("railwatch.detectors.context_glr:ContextGLR",
                         "railwatch's own: blind-spot network predicting every sample and its "
                         "noise scale from the context, spike/box GLR scan of the residual"),
    "nuisance-glr": Entry("railwatch.detectors.nuisance_glr:NuisanceGLR",
                          "railwatch's own, no network: harmonic model of the vibration, the "
                          "recording's noise floor, spike/box GLR scan of the residual"),
    "matched-filter": Entry("railwatch.detectors.matched_filter:MatchedFilter",
                            "classical baseline: robust linear predictor + matched filters for "
                            "spikes and 5-20-sample boxes, no network", role="reference"),
    "oracle": Entry("railwatch.detectors.oracle:Oracle",
                    "ceiling (synthetic data only): GLR test on the residual whitened with the "
                    "generator's true nuisance signal and noise std", role="ceiling"),
}

#: The reconstruction models that also get a ``NAME+glr`` row: the same trained network (bench
#: cells share it), its signed residual scored by the scan every GLR detector shares instead of
#: its own score, so that the benchmark separates what the model contributes from the scoring.
GLR_VARIANTS = ("lstm-ed", "cnn-ae", "mscred", "anomaly-transformer", "aft-reconstruction")
REGISTRY.update({
    f"{name}{GLR_SUFFIX}": Entry(REGISTRY[name].target,
                         f"{name}'s residual scored by the shared GLR scan (noise scale with one "
                         "change point, spike and 5-20-sample box tests) instead of its own score",
                         {**REGISTRY[name].overrides, "scoring": GLR_SCORING}, variant_of=name)
    for name in GLR_VARIANTS})


def names() -> list[str]:
    return list(REGISTRY)


def role(name: str) -> str:
    """The entry's role (:data:`ROLES`); a name the registry does not hold is ``learned``."""
    entry = REGISTRY.get(name)
    return entry.role if entry is not None else "learned"


def ceiling(detectors: Sequence[str]) -> str | None:
    """The first of ``detectors`` whose role is the ceiling, or None."""
    return next((d for d in detectors if role(d) == "ceiling"), None)


def variant_of(name: str) -> str:
    """The entry whose trained network this row scores another way (``cnn-ae`` for
    ``cnn-ae+glr``), or the name itself."""
    entry = REGISTRY.get(name)
    return entry.variant_of if entry is not None and entry.variant_of else name


def class_for(name: str) -> type[Detector]:
    """The detector class registered under ``name``."""
    if name not in REGISTRY:
        raise RailwatchError(f"unknown detector {name!r}; available: {', '.join(REGISTRY)}")
    module, cls = REGISTRY[name].target.split(":")
    return getattr(importlib.import_module(module), cls)  # type: ignore[no-any-return]


def create(name: str, overrides: Mapping[str, Any] | None = None) -> Detector:
    """A new, unfitted detector: the entry's overrides, then the caller's (unknown keys raise)."""
    cls = class_for(name)
    config = config_from_dict(cls.Config, {**REGISTRY[name].overrides, **(overrides or {})})
    det = cls(config)
    det.registry_name = name
    return det


def load_detector(path: str | os.PathLike[str]) -> Detector:
    """Load a detector saved with :meth:`Detector.save`; any detector class, by its header.

    Every way a model folder can be damaged (a file missing, truncated, replaced or edited; a
    header naming another detector, a newer format or settings this version does not know) is
    a one-line :class:`RailwatchError` naming the folder; the loaded detector has scored a
    window, so that it does not fail later, in the middle of a recording.
    """
    path = Path(path)
    model_folder.check_folder(path)
    try:
        header = model_folder.read_header(path)
        cls = class_for(header["detector"])
        det = cls._from_saved(header, path)
        det.registry_name = header["detector"]
        return det
    except RailwatchError as e:
        raise naming(str(path), e) from None
    except Exception as e:  # noqa: BLE001 - any failure to read a saved model is the same to the user
        raise RailwatchError(
            f"{path} is not a readable railwatch model directory ({type(e).__name__}: "
            f"{one_line(e)[:200]})"
        ) from None
