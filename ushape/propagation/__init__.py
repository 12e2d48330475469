"""Uncertainty propagation: a Gaussian over the latent code -> mean and variance of the SDF at points."""

from ushape.decoder.query import decode_points, frozen
from ushape.propagation.field import BandField, decode_field, field_uncertainty, narrow_band_field
from ushape.propagation.linearised import latent_variance, propagate_linearised
from ushape.propagation.mesh import (
    METHODS,
    SDF_CLAMP,
    clamped_sdf_errors,
    clamped_sdf_predictions,
    grid_points,
    propagate,
    propagate_to_sdf,
    vertex_uncertainty,
)
from ushape.propagation.monte_carlo import propagate_mc

__all__ = [
    "METHODS",
    "SDF_CLAMP",
    "BandField",
    "clamped_sdf_errors",
    "clamped_sdf_predictions",
    "decode_field",
    "decode_points",
    "field_uncertainty",
    "frozen",
    "grid_points",
    "latent_variance",
    "narrow_band_field",
    "propagate",
    "propagate_linearised",
    "propagate_mc",
    "propagate_to_sdf",
    "vertex_uncertainty",
]
