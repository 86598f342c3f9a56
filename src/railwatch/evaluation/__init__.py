"""Evaluation: the metrics, localisation and timing of scored windows, and the scores file."""
