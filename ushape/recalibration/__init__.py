"""Post-hoc recalibration of the predicted variance (temperature scaling): latent, and propagated SDF."""

from ushape.recalibration.temperature import (
    apply_temperature,
    fit_calibration_temperature,
    fit_calibration_temperature_across,
    fit_temperature,
    gaussian_nll_with_temperature,
)

__all__ = [
    "apply_temperature",
    "fit_calibration_temperature",
    "fit_calibration_temperature_across",
    "fit_temperature",
    "gaussian_nll_with_temperature",
]
