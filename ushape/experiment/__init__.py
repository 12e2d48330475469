"""Experiment orchestration: what the entry scripts (train.py, ...) call."""
