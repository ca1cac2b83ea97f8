"""Evaluation: synthetic scenes with ground truth (and, later, the field's metrics and dataset readers)."""
