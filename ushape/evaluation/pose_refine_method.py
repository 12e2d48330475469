"""The pose-and-shape refinement as a method of the evaluation: rows "<encoder> + refine (masks, pose estimated)",
and "refine (depth, pose estimated)" where the views' depth maps are read too (an RGB-D camera).

The same views, crops and prior as `refine_method.RefineMethod`'s "refine (masks)" rows, with the object's pose
hidden: each view keeps its K (and the crop's shift in it), and the views of one instance keep their motion
relative to the first (as odometry or R2N2's rows with the object's frame hidden would give), so they share one
estimated pose (`ushape.refinement.joint`). Where the run has a viewpoint head, the hypotheses start from what
each view's image (as the encoder saw it, cropped) says of its azimuth. Cached like the known-camera rows.
"""

from __future__ import annotations

import hashlib
from dataclasses import replace
from typing import Sequence

import torch

from ushape import atomic
from ushape.evaluation.refine_method import EvaluationView, RefineMethod, evaluation_view
from ushape.evaluation.views import Estimate, ViewKey, encoder_inputs
from ushape.reconstruction.pose_calibration import pose_settings_for
from ushape.refinement import MODES
from ushape.refinement.joint import PoseGroups, PoseSettings
from ushape.refinement.pose_search import refine_pose_and_shape


class PoseRefineMethod(RefineMethod):
    """Refinement on the masks, or masks and depth, with the object's pose estimated
    (conf/method/refine_masks_pose.yaml, refine_depth_pose.yaml); the settings are RefineMethod's, and `pose` sets
    the search's (`ushape.refinement.joint.PoseSettings` fields, e.g. {azimuths: 4})."""

    def __init__(self, mode: str = "masks", *args, pose: dict | None = None, **kwargs) -> None:
        kwargs.setdefault("name", f"refine_{mode}_pose")
        kwargs.setdefault("label", f"refine ({mode}, pose estimated)")
        super().__init__(mode, *args, **kwargs)
        self.pose_settings = PoseSettings(**dict(pose or {}))
        if self.settings.mode not in MODES:
            raise ValueError(f"{self.name}: the pose is estimated from masks, or masks and depth; mode: masks|depth")

    def after_fusion(self, context, fused: Estimate, keys: Sequence[ViewKey], min_scale: float) -> Estimate:
        run, seed = context.run, context.settings.seed
        cache = self.cache_file(context, fused, keys, min_scale)
        if cache is not None:
            search = hashlib.sha1(repr(self.pose_settings_for(run)).encode()).hexdigest()[:8]
            cache = cache.with_name(f"pose_{search}_{cache.name}")
            if cache.is_file():
                blob = torch.load(cache, map_location="cpu", weights_only=False)
                return Estimate(blob["mu"], blob["cov"], blob["fallback"])
        views = [evaluation_view(EvaluationView(run.world, key, min_scale, seed)) for key in keys]
        if any(v is None for v in views):  # no camera to keep K and the relative motion from: the prior
            estimate = Estimate(fused.mu, fused.var, "no camera")
        else:
            groups = PoseGroups.from_cameras([v.world_to_cam for v in views])
            logp = self.azimuth_log_probs(run, keys, min_scale, seed)
            try:
                post = refine_pose_and_shape(
                    run.predictor.decoder,
                    fused.mu,
                    fused.var,
                    views,
                    groups,
                    self.settings_for(run),
                    self.pose_settings_for(run),
                    azimuth_logp=logp,
                )
                estimate = Estimate(post.mu, post.cov, None)
            except ValueError as err:  # an empty or full mask in a crop: no outline to place the object by
                estimate = Estimate(fused.mu, fused.var, str(err))
        if cache is not None:
            atomic.torch_save({"mu": estimate.mu, "cov": estimate.var, "fallback": estimate.fallback}, cache)
        return estimate

    def pose_settings_for(self, run) -> PoseSettings:
        """The search's settings; where `calibrated`, with the run's fitted pose information scale
        (`reconstruct.py --fit-pose`) unless the method's `pose` sets one."""
        if not self.calibrated or self.pose_settings.pose_information_scale is not None:
            return self.pose_settings
        fitted = pose_settings_for(run.predictor.checkpoint, self.settings.mode).pose_information_scale
        return replace(self.pose_settings, pose_information_scale=fitted)

    @staticmethod
    def azimuth_log_probs(run, keys: Sequence[ViewKey], min_scale: float, seed: int) -> list | None:
        """Each view's azimuth distribution from the run's viewpoint head, on the image the encoder saw."""
        predictor = run.predictor
        if getattr(predictor, "viewpoint", None) is None:
            return None
        images = encoder_inputs(predictor, run.world, keys, min_scale, seed)
        return list(predictor.azimuth_log_probs(images))
