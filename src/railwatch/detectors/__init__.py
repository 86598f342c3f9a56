"""Unsupervised detectors behind one API (see :mod:`railwatch.detectors.base`)."""

from railwatch.detectors.base import Detector, Localization, Scores, load_detector
from railwatch.detectors.registry import REGISTRY, create, names

__all__ = ["REGISTRY", "Detector", "Localization", "Scores", "create", "load_detector", "names"]
