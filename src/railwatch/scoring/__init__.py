"""Scoring: from what a detector computes (a residual, a whitened signal) to anomaly scores.

Data flows one way: ``detectors`` → ``scoring`` → ``evaluation``. Nothing here imports a
detector or torch. :mod:`railwatch.scoring.glr` holds the generalised likelihood-ratio scan for
the benchmark's two anomaly shapes (a one-sample spike, boxes of 5–20 samples), calibrated to
family-wise p-values so that the two families' maxima compare; the oracle and the matched filter
score with it.
"""
