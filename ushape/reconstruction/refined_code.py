"""The fused code refined on the input views (`ushape.refinement`), as reconstruct.py applies it: the views'
cameras, masks and depth, the stored --fit-refinement calibration, and the record summary.json keeps."""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Sequence

import torch

from ushape.data.layout import WorldIndex
from ushape.fusion.rules import FusedCode
from ushape.reconstruction.predictor import Predictor
from ushape.reconstruction.settings import ReconstructionSettings
from ushape.refinement import MODES, ObservedView, refine, refine_settings
from ushape.refinement.inputs import (
    R2N2Frame,
    input_views,
    relative_pose_groups,
    typical_r2n2_frame,
    unposed_views,
)
from ushape.refinement.joint import PoseGroups, PoseSettings
from ushape.refinement.pose_search import refine_pose_and_shape
from ushape.workspace import CONFIG_FILE

log = logging.getLogger(__name__)
# What summary.json's refinement record keeps of the calibration it applied (reconstruct.py --fit-refinement).
APPLIED = ("information_scale", "sdf_temperature", "sdf_view_exponent", "sdf_floor", "seen", "size", "n_shapes")


def refined(
    decoder: torch.nn.Module,
    fused: FusedCode,
    inputs: Sequence[str | Path],
    paths: Sequence[Path],  # the inputs that could be read
    observations: Sequence[ObservedView | None] | None,  # one per input
    settings: ReconstructionSettings,
    calibration: dict[str, Any] | None = None,  # --fit-refinement's fit for this mode (None: none)
    r2n2_frame: R2N2Frame | None = None,  # R2N2's frame in the model's, for R2N2 renders' cameras
    masks: Sequence[Path] | None = None,  # the mask files of `paths` (pose estimation reads them)
    # () -> [V, bins] per path, the viewpoint head's azimuth log-probabilities (or None): asked only where the pose
    # is estimated, so a refinement through known cameras pays no second backbone pass
    viewpoint: Callable[[], torch.Tensor | None] | None = None,
    pose_settings: PoseSettings | None = None,  # the pose search's (its fitted pose information scale)
) -> tuple[FusedCode, dict[str, Any], list[ObservedView]]:
    """The fused code refined on the views (FusedCode with var the full covariance [D, D]), its record and the
    views it was refined on; with a calibration, the posterior at its information scale s, and the record
    carries the calibration."""
    if observations is None:
        views = input_views(paths, r2n2_frame=r2n2_frame)
    elif len(observations) != len(inputs):
        raise ValueError(f"{len(observations)} observed views for {len(inputs)} input images: pass one per image")
    else:
        by_input = dict(zip((Path(i) for i in inputs), observations))
        views = [by_input[Path(p)] for p in paths]
    scale = 1.0 if calibration is None else float(calibration["information_scale"])
    if calibration is not None and calibration.get("size") != settings.refine_size:
        log.warning(
            "the refinement's calibration was fitted at %s rays a side, this refinement uses %d: refit with "
            "`reconstruct.py --fit-refinement %s --refine-size %d`",
            calibration.get("size"),
            settings.refine_size,
            settings.refine,
            settings.refine_size,
        )
    options = refine_settings(
        settings.refine, settings.refine_size, information_scale=scale, starts=settings.refine_starts
    )
    if estimates_pose(settings, views):
        return pose_refined(
            decoder, fused, paths, views, settings, options, calibration, masks, viewpoint, pose_settings
        )
    posterior = refine(decoder, fused.mu, fused.var, views, options)
    record = {"mode": settings.refine, "starts": settings.refine_starts, **posterior.record()}
    record["views_with_camera"] = sum(v is not None for v in views)
    record["views_refined"] = sum(v["used"] is not None for v in posterior.views)  # what its SDF factor is read at
    record["calibration"] = None if calibration is None else {k: calibration.get(k) for k in APPLIED}
    record["mu"] = posterior.mu.tolist()
    views = [v for v in views if v is not None]
    if posterior.fallback is not None:  # the prior exactly, in its own (diagonal) form
        return fused, record, views
    return FusedCode(posterior.mu, posterior.cov, fused.kept), record, views


def estimates_pose(settings: ReconstructionSettings, views: Sequence[ObservedView | None]) -> bool:
    """Whether the object's pose is estimated: asked (--pose estimate, or --relative-poses given), on masks or on
    masks and depth (a camera file's `depth`, in any units: it gives the object's distance and size), or by
    default (auto) where the refinement is on masks and no view has a camera (an image alone has no depth map)."""
    if settings.pose == "given" or settings.refine not in MODES:
        return False
    if settings.pose == "estimate" or settings.relative_poses:
        return True
    return settings.refine == "masks" and all(v is None for v in views)


def pose_refined(
    decoder, fused, paths, views, settings, options, calibration, masks, viewpoint=None, pose_settings=None
):
    """The fused code and the object's pose refined together (`refine_pose_and_shape`): every view its own pose,
    or one shared by all where --relative-poses gives their motion; the hypotheses start where the viewpoint head
    (`viewpoint`: its azimuth log-probabilities [V, bins]) says the cameras stood, where the model has one."""
    unposed = unposed_views(paths, views, masks, settings.fov)
    groups = (
        relative_pose_groups(settings.relative_poses, len(unposed))
        if settings.relative_poses
        else PoseGroups.separate(len(unposed))
    )
    azimuth_logp = None if viewpoint is None else viewpoint()
    logps = None if azimuth_logp is None else list(azimuth_logp)
    pose_settings = capture_settings(pose_settings or PoseSettings(), settings)
    posterior = refine_pose_and_shape(decoder, fused.mu, fused.var, unposed, groups, options, pose_settings, logps)
    record = {"mode": settings.refine, "starts": 0, **posterior.record()}
    record["pose"]["viewpoint_head"] = azimuth_logp is not None
    record["pose"]["pose_information_scale"] = pose_settings.pose_information_scale
    record["pose"]["elevation_deg"] = pose_settings.elevation
    record["pose"]["tilt_prior_deg"] = pose_settings.tilt_prior_deg
    record["views_with_camera"] = sum(v is not None for v in views)
    record["views_refined"] = len(unposed)  # every view, each through its estimated camera
    record["calibration"] = None if calibration is None else {k: calibration.get(k) for k in APPLIED}
    record["mu"] = posterior.mu.tolist()
    return FusedCode(posterior.mu, posterior.cov, fused.kept), record, posterior.posed_views(unposed)


def capture_settings(pose_settings: PoseSettings, settings: ReconstructionSettings) -> PoseSettings:
    """The pose search's settings with what --elevation and --tilt-std say of the cameras, where given."""
    given = {"elevation": settings.elevation, "tilt_prior_deg": settings.tilt_std}
    return replace(pose_settings, **{k: v for k, v in given.items() if v is not None})


def r2n2_frame_of(predictor: Predictor) -> R2N2Frame | None:
    """Where R2N2's frame sits in the predictor's model: its own record (a shipped model), else its run's world."""
    if predictor.r2n2_frame is not None:
        return predictor.r2n2_frame
    if predictor.world is not None and (Path(predictor.world) / CONFIG_FILE).is_file():
        return typical_r2n2_frame(WorldIndex.load(predictor.world))
    return None
