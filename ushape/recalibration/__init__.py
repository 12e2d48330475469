"""Post-hoc recalibration of the predicted variance (temperature scaling): latent, and propagated SDF."""

from ushape.recalibration.temperature import (
    apply_temperature,
    fit_calibration_temperature,
    fit_calibration_temperature_across,
    fit_calibration_temperature_and_floor,
    fit_temperature,
    floor_grid,
    gaussian_nll_with_temperature,
)

__all__ = [
    "apply_temperature",
    "fit_calibration_temperature",
    "fit_calibration_temperature_across",
    "fit_calibration_temperature_and_floor",
    "fit_temperature",
    "floor_grid",
    "gaussian_nll_with_temperature",
]
