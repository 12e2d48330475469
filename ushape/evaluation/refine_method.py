"""The refinement as a reconstruction method of the evaluation: rows "<encoder> + refine (masks|depth)".

Its `after_fusion` step refines a Gaussian, one view's or an instance's fused by a table's rule, on the
views it came from (`ushape.refinement.refine`: Levenberg-Marquardt on their masks, or masks and depth,
and the full-covariance Laplace posterior). Each view is the one the encoder was shown: the test render's
camera, mask (views.npz, else the image's alpha) and depth, cropped to the very box the evaluation cropped
the image to at that min scale (`augment.corrupted_box`, seeded by `view_seed`), at the box's own pixels,
so the camera changes only by the crop's shift (`crop_view`). A render without cameras gives no view, and
the refinement falls back to the prior (counted, see methods).

Refinement costs seconds per view, so each result is cached under the evaluation's cache folder, keyed by
the encoder (checkpoint and temperature), the decoder, the world, the settings, the views, the crop and
the prior refined (which tells the fusion rules apart), and written atomically.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from PIL import Image

from ushape import atomic
from ushape.data.augment import corrupted_box, load_rgba, view_seed
from ushape.data.layout import WorldIndex
from ushape.errors import InputError
from ushape.evaluation.methods import ReconstructionMethod
from ushape.evaluation.views import Estimate, ViewKey, encoder_tag
from ushape.fusion.strategies import check_optional_number
from ushape.recalibration.refine_information import refined_sdf_temperature
from ushape.reconstruction.refine_calibration import read_refinement_calibration
from ushape.refinement import ObservedView, RefineSettings, crop_view, refine, refine_settings, world_views

CACHE_FOLDER = "refine"


@dataclass(frozen=True)
class EvaluationView:
    """Where a test view's pixels come from and how the evaluation cropped it."""

    world: WorldIndex
    key: ViewKey
    min_scale: float
    seed: int


def stored_view(world: WorldIndex, key: ViewKey) -> ObservedView | None:
    """A test render's camera, mask and depth (views.npz; the mask from the image's alpha where views.npz
    has none); None where the render has no camera (a photo)."""
    path = world.views_path(key.shape_id)
    if not path.is_file():
        return None
    with np.load(path) as data:
        has_masks = "masks" in data.files
        K, w2c = data["K"][key.view].astype(np.float64), data["world_to_cam"][key.view].astype(np.float64)
        depth = torch.as_tensor(data["depth"][key.view]).float() if "depth" in data.files else None
    if has_masks:
        return world_views(path, [key.view])[0]
    alpha = load_rgba(world.image_path(key.shape_id, key.view))[3]
    return ObservedView(K, w2c, (alpha > 0.5).float(), depth)


def evaluation_view(where: EvaluationView) -> ObservedView | None:
    """The view as the encoder was shown it: cropped to the evaluation's box for (seed, view, min scale)."""
    view = stored_view(where.world, where.key)
    if view is None:
        return None
    with Image.open(where.world.image_path(where.key.shape_id, where.key.view)) as image:  # the header only
        width, height = image.size
    if view.image_hw != (height, width):
        raise ValueError(
            f"{where.world.views_path(where.key.shape_id)}: view {where.key.view}'s mask is {view.image_hw} "
            f"but its image is {(height, width)}; the crop box is in the image's pixels: rebuild the world"
        )
    box = corrupted_box(height, width, where.min_scale, view_seed(where.seed, where.key.shape_id, where.key.view))
    return crop_view(view, box, (box[2], box[3]))


class RefineMethod(ReconstructionMethod):
    """Refinement on the views (conf/method/refine_masks.yaml, refine_depth.yaml): mode masks or depth, size
    rays per image side, the residuals' stds, the iterations and the information scale s of the Laplace
    covariance (Sigma^-1 + s J^T W J)^-1 (1: every ray counted as independent; a value fitted on val with
    ushape.recalibration.refine_information) (see ushape.refinement.RefineSettings); sdf_temperature and
    sdf_floor, the posterior's SDF variance T_sdf var + floor^2 (fitted on val with
    `refine_information.fit_sdf_recalibration`; None: the run's single-view T_sdf). calibrated: s, T_sdf and
    the floor from each run's own fit instead (`reconstruct.py --fit-refinement MODE`, refinement_calibration.json
    beside its checkpoint). starts: prior draws scored beside the fused mean, the LM starting from the lowest
    energy (0: from the mean; docs/refinement.md, "Starts"). A setting not given is conf/refine.yaml's."""

    def __init__(
        self,
        mode: str = "masks",
        size: int | None = None,
        sigma_mask: float | None = None,
        sigma_depth: float | None = None,
        iterations: int | None = None,
        information_scale: float | None = None,
        sdf_temperature: float | None = None,
        sdf_floor: float | None = None,
        calibrated: bool = False,
        name: str | None = None,
        label: str | None = None,
        starts: int | None = None,
    ) -> None:
        self.settings = refine_settings(mode, size, sigma_mask, sigma_depth, iterations, information_scale, starts)
        self.calibrated = bool(calibrated)
        temperature = check_optional_number(sdf_temperature, "sdf_temperature")
        floor = check_optional_number(sdf_floor, "sdf_floor", zero_ok=True)
        if temperature is not None or floor is not None:
            self.sdf_calibration = (1.0 if temperature is None else temperature, floor)
        self.name = name or f"refine_{mode}"
        self.label = label or f"refine ({mode})"

    def run_calibration(self, run) -> dict | None:
        """The run's --fit-refinement fit for this mode where `calibrated` (an error says how to make it), else None."""
        if not self.calibrated:
            return None
        fit = read_refinement_calibration(run.predictor.checkpoint, self.settings.mode)
        if fit is None:
            raise InputError(
                f"{self.name}: calibrated, but {run.predictor.checkpoint} has no refinement calibration for "
                f"{self.settings.mode}; fit it with `python reconstruct.py --fit-refinement {self.settings.mode} "
                f"--checkpoint {run.predictor.checkpoint} --refine-size {self.settings.observation.size}`"
            )
        return fit

    def settings_for(self, run) -> RefineSettings:
        """The settings a run's views are refined with: the run's fitted information scale where `calibrated`."""
        fit = self.run_calibration(run)
        return self.settings if fit is None else replace(self.settings, information_scale=fit["information_scale"])

    def sdf_calibration_for(self, run, n_views: int = 1) -> tuple[float, float | None] | None:
        """The run's fitted (T_sdf n^beta, floor) at n_views views where `calibrated`, else `sdf_calibration`."""
        fit = self.run_calibration(run)
        if fit is None:
            return self.sdf_calibration
        return refined_sdf_temperature(fit, n_views), fit["sdf_floor"] or None

    def after_fusion(self, context, fused: Estimate, keys: Sequence[ViewKey], min_scale: float) -> Estimate:
        """`fused` refined on the views `keys` as the evaluation cropped them at min_scale (cached)."""
        run, seed = context.run, context.settings.seed
        cache = self.cache_file(context, fused, keys, min_scale)
        if cache is not None and cache.is_file():
            blob = torch.load(cache, map_location="cpu", weights_only=False)
            return Estimate(blob["mu"], blob["cov"], blob["fallback"])
        views = [evaluation_view(EvaluationView(run.world, key, min_scale, seed)) for key in keys]
        posterior = refine(run.predictor.decoder, fused.mu, fused.var, views, self.settings_for(run))
        estimate = Estimate(posterior.mu, posterior.cov, posterior.fallback)
        if cache is not None:
            atomic.torch_save({"mu": estimate.mu, "cov": estimate.var, "fallback": estimate.fallback}, cache)
        return estimate

    def cache_file(self, context, fused: Estimate, keys: Sequence[ViewKey], min_scale: float) -> Path | None:
        """Where this refinement's result is kept (None: the evaluation keeps no cache)."""
        if context.cache_dir is None:
            return None
        run = context.run
        prior = hashlib.sha1(fused.mu.float().numpy().tobytes() + fused.var.float().numpy().tobytes()).hexdigest()
        views = "|".join(f"{k.shape_id}/{k.view}" for k in keys)
        text = (
            f"{encoder_tag(run.predictor)}|{run.reconstructor.decoder_tag}|{Path(run.world.root).resolve()}|"
            f"{self.settings_for(run)}|{views}|{min_scale:g}|{context.settings.seed}|{prior}"
        )
        return Path(context.cache_dir) / CACHE_FOLDER / f"{hashlib.sha1(text.encode()).hexdigest()[:24]}.pt"
