"""Scoring: from what a detector computes (a residual, a whitened signal) to anomaly scores.

Data flows one way: ``detectors`` → ``scoring`` → ``evaluation``. Nothing here imports a
detector or torch. :mod:`railwatch.scoring.glr` holds the generalised likelihood-ratio scan for
the benchmark's two anomaly shapes (a one-sample spike, boxes of 5–20 samples), calibrated to
family-wise p-values so that the two families' maxima compare; the oracle and the matched filter
score with it. :mod:`railwatch.scoring.residual` standardises a model's residual by a noise scale
estimated from it and runs that scan: context-glr scores with it, and so does every
reconstruction model's ``scoring=glr`` row (``TorchDetector.glr_scores``).
"""

#: The registry suffix of a reconstruction model's row scored by the shared GLR scan of its
#: residual (``cnn-ae+glr``: ``scoring=glr``, :class:`railwatch.scoring.residual.ResidualGLR`).
GLR_SUFFIX = "+glr"
