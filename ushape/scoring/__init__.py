"""Proper scores and calibration of Gaussian predictions: shared building blocks, torch only.

    calibration   calibration curves, calibration error and their plot (matplotlib imported when plotting)
    scores        univariate Gaussian NLL and Energy Score (CRPS) in closed form

Training (encoder), recalibration and evaluation all score predictions the same way; keeping the
scores here, below all of them, lets each import them without importing the others.
"""
