"""Evaluation: reconstruction metrics, calibration plots and proper scores for predicted uncertainty.

Import the module you need (e.g. `ushape.evaluation.calibration`); this package imports
nothing itself, so `import ushape.evaluation.scores` does not pull in matplotlib.
"""
