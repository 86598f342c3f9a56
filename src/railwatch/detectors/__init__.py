"""Unsupervised detectors behind one API (:mod:`railwatch.detectors.api`), by name
(:mod:`railwatch.detectors.registry`); deep ones share :mod:`railwatch.detectors.training`, and
a fitted one is a model folder (:mod:`railwatch.detectors.model_folder`)."""

from railwatch.detectors.api import Detector, Scores
from railwatch.detectors.registry import REGISTRY, create, load_detector, names
from railwatch.scoring.reduce import Localization

__all__ = ["REGISTRY", "Detector", "Localization", "Scores", "create", "load_detector", "names"]
