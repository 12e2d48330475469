"""The fused code refined on what calibrated views show (masks, depth): MAP and full-covariance Laplace posterior."""

from ushape.refinement.observation import ObservationSettings, residuals
from ushape.refinement.posterior import MODES, Posterior, RefineSettings, refine, refine_settings
from ushape.refinement.views import ObservedView, crop_camera, crop_view, world_views

__all__ = [
    "MODES",
    "ObservationSettings",
    "ObservedView",
    "Posterior",
    "RefineSettings",
    "crop_camera",
    "crop_view",
    "refine",
    "refine_settings",
    "residuals",
    "world_views",
]
