"""Post-hoc recalibration of the predicted variance (temperature scaling): latent, and propagated SDF."""

from ushape.recalibration.sdf_distance import DistanceFit, distance_variance, fit_sdf_distance_calibration
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
    "DistanceFit",
    "distance_variance",
    "fit_sdf_distance_calibration",
    "apply_temperature",
    "fit_calibration_temperature",
    "fit_calibration_temperature_across",
    "fit_calibration_temperature_and_floor",
    "fit_temperature",
    "floor_grid",
    "gaussian_nll_with_temperature",
]
