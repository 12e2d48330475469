"""Fit the temperatures of a trained run on its val split and keep them beside the checkpoint.

Latent: T (var' = T var) minimising the NLL of the val codes, the stage-1 codes `codes_val.pt` of the
run's decoder (latent-optimised with the decoder frozen); the images are the world's renders, prepared
as evaluation prepares them. SDF: the variance propagated (linearised) from the T-scaled latent
Gaussians to each val shape's ground-truth SDF samples is still too small (measured 1.04-1.24x in std,
docs/stage2_encoder.md), so a second factor, T_sdf on that variance, is fitted to its calibration error
there, on the first views of each shape as `eval.py` scores them. Shared error: the error every view of a
val shape shares, S [D], and the views' own scale c, on the T-scaled variances
(`ushape.recalibration.shared_error`), for the `shared` fusion rule.
`temperature.json` = {"temperature", "n_images", "nll_before", "nll_after", "shared_error": {"var",
"view_scale", "n_shapes"}, "sdf_temperature", "sdf_calibration_before", "sdf_calibration_after",
"sdf_views", "checkpoint", "world"}.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch.utils.data import DataLoader

from ushape import atomic
from ushape.data.layout import WorldIndex
from ushape.data.sdf_dataset import sdf_points
from ushape.decoder.artifacts import codes_file, load_codes
from ushape.encoder.datamodule import RenderDataset
from ushape.propagation import SDF_CLAMP, propagate_to_sdf
from ushape.recalibration.shared_error import fit_shared_error
from ushape.recalibration.temperature import (
    apply_temperature,
    fit_calibration_temperature,
    fit_temperature,
    gaussian_nll_with_temperature,
)
from ushape.reconstruction.predictor import Predictor, temperature_path


def val_predictions(
    predictor: Predictor, world: str | Path, batch_size: int = 32, split: str = "val"
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, list[str]]:
    """(mu [N, D], var [N, D], code [N, D], shape id per render) of every render of a split (val), without
    any temperature."""
    codes = load_codes(Path(predictor.model.hparams.decoder_path) / codes_file(split))
    dataset = RenderDataset(world, split, codes, predictor.image_size)
    saved, predictor.temperature = predictor.temperature, None
    mus, variances, targets, shape_ids = [], [], [], []
    try:
        for batch in DataLoader(dataset, batch_size=batch_size):
            mu, var = predictor.encode(batch["image"])
            mus.append(mu), variances.append(var), targets.append(batch["code"])
            shape_ids += list(batch["shape_id"])
    finally:
        predictor.temperature = saved
    return torch.cat(mus), torch.cat(variances), torch.cat(targets), shape_ids


def sdf_errors(
    predictor: Predictor,
    world: WorldIndex,
    mu: torch.Tensor,  # [N, D]
    var: torch.Tensor,  # [N, D], already T-scaled
    shape_ids: list[str],
    views_per_shape: int = 4,
    n_points: int = 1024,
) -> tuple[torch.Tensor, torch.Tensor, int]:
    """(|error| [P], std [P], views used) of the linearised SDF prediction at each shape's ground-truth SDF
    samples, clamped as evaluation clamps them, for the first `views_per_shape` renders of each val shape."""
    errors, stds, seen = [], [], {}
    for i, shape_id in enumerate(shape_ids):
        seen[shape_id] = seen.get(shape_id, 0) + 1
        if seen[shape_id] > views_per_shape:
            continue
        points, sdf_true = sdf_points(world, shape_id, n_points)
        mean, variance = propagate_to_sdf(predictor.decoder, mu[i], var[i], points, "linearised", clamp=SDF_CLAMP)
        errors.append((mean - sdf_true.clamp(-SDF_CLAMP, SDF_CLAMP)).abs())
        stds.append(variance.sqrt())
    return torch.cat(errors), torch.cat(stds), len(errors)


def fit_and_store_temperature(predictor: Predictor, world: str | Path | None = None) -> dict[str, Any]:
    """Fit T (and T_sdf where the world has SDF samples) on the val split, write temperature.json beside the
    checkpoint, return its content."""
    world = world or predictor.world
    if world is None:
        raise ValueError("which world's val split? pass a run folder (its run.json names the world) or `world=`")
    mu, var, code, shape_ids = val_predictions(predictor, world)
    temperature = fit_temperature(mu, var, code)
    record = {
        "temperature": temperature,
        "n_images": int(mu.shape[0]),
        "nll_before": gaussian_nll_with_temperature(mu, var, code, 1.0),
        "nll_after": gaussian_nll_with_temperature(mu, var, code, temperature),
    }
    if len(set(shape_ids)) < len(shape_ids):  # several views of a shape: what they share can be told apart
        record["shared_error"] = fit_shared_error(mu, apply_temperature(var, temperature), code, shape_ids).to_record()
    index = WorldIndex(Path(world), category="", splits={})  # only its per-shape paths are read
    if all(index.sdf_path(s).is_file() for s in set(shape_ids)):  # a real-data world may have no SDF samples
        error, std, views = sdf_errors(predictor, index, mu, apply_temperature(var, temperature), shape_ids)
        sdf_temperature, before, after = fit_calibration_temperature(error, std)
        record.update(
            sdf_temperature=sdf_temperature,
            sdf_calibration_before=before,
            sdf_calibration_after=after,
            sdf_views=views,
        )
    record.update(checkpoint=str(predictor.checkpoint), world=str(world))
    atomic.write_json(temperature_path(predictor.checkpoint), record)
    return record
