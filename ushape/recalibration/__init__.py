"""Post-hoc recalibration of the encoder's predicted latent variance (temperature scaling)."""

from ushape.recalibration.temperature import (
    apply_temperature,
    fit_calibration_temperature,
    fit_temperature,
    gaussian_nll_with_temperature,
)

__all__ = ["apply_temperature", "fit_calibration_temperature", "fit_temperature", "gaussian_nll_with_temperature"]
