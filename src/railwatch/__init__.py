"""railwatch: unsupervised detection and localisation of small transient rail defects."""

__version__ = "0.1.0"
