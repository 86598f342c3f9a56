"""Evaluation: metrics, localisation, timing, tables, figures and the report."""
