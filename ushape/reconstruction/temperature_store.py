"""Fit the temperatures of a trained run on its val split and keep them beside the checkpoint.

Latent: T (var' = T var) minimising the NLL of the val codes, the stage-1 codes `codes_val.pt` of the
run's decoder (latent-optimised with the decoder frozen); the images are the world's renders, prepared
as evaluation prepares them. SDF: the variance propagated (linearised) from the T-scaled latent
Gaussians to each val shape's ground-truth SDF samples is still too small (measured 1.04-1.24x in std,
docs/stage2_encoder.md), so a second factor, T_sdf on that variance, is fitted to its calibration error
there, on the first views of each shape as `eval.py` scores them. Shared error: the error every view of a
val shape shares, S [D], and the views' own scale c, on the T-scaled variances
(`ushape.recalibration.shared_error`), for the `shared` fusion rule, and that rule's own SDF temperature:
the shared rule's fused variance is not a single view's (S moves variance between latent dimensions, so the
decoder's Jacobian sees another mix), so its factor is fitted on it, the val views fused 1, 3 and 10 at a
time as Table V fuses the test views, with a floor where it lowers the worst calibration error: the
decoder's own SDF misfit at the val shapes' own codes (an error no code's variance expresses), measured and
added as a std, and a term that grows with the distance from the predicted surface, where the fused error
grows and the propagated std does not: T_sdf var + floor^2 + (b |clamp(mean)|)^2, T_sdf and b fitted to the
worst calibration error over the three view counts, on all samples and near the surface
(`ushape.recalibration.sdf_distance`).
`temperature.json` = {"temperature", "n_images", "nll_before", "nll_after", "shared_error": {"var",
"view_scale", "n_shapes", "sdf_temperature", "sdf_floor", "sdf_distance_scale", "sdf_decoder_misfit",
"sdf_view_counts", "sdf_calibration_before", "sdf_calibration_after", "sdf_calibration_worst"},
"sdf_temperature", "sdf_calibration_before",
"sdf_calibration_after", "sdf_views", "checkpoint", "world"}.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import torch
from torch.utils.data import DataLoader

from ushape import atomic
from ushape.data.layout import WorldIndex
from ushape.data.sdf_dataset import sdf_points
from ushape.decoder.artifacts import codes_file, load_codes
from ushape.decoder.query import code_sdf_fn, frozen
from ushape.encoder.datamodule import RenderDataset
from ushape.fusion import SharedErrorFusion
from ushape.fusion.subsets import view_subsets
from ushape.propagation import SDF_CLAMP, clamped_sdf_predictions, propagate_to_sdf
from ushape.recalibration.sdf_distance import fit_sdf_distance_calibration
from ushape.recalibration.shared_error import SharedError, fit_shared_error
from ushape.recalibration.temperature import (
    apply_temperature,
    fit_calibration_temperature,
    fit_temperature,
    gaussian_nll_with_temperature,
)
from ushape.reconstruction.predictor import Predictor, temperature_path

# The numbers of val views fused at a time on which the shared rule's SDF temperature is fitted (Table V's).
SHARED_SDF_VIEW_COUNTS = (1, 3, 10)


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


def fused_sdf_errors(
    predictor: Predictor,
    world: WorldIndex,
    rule,  # (mu [R, n, D], var [R, n, D]) -> FusedCode, as ushape.fusion's rules
    mu: torch.Tensor,  # [N, D]
    var: torch.Tensor,  # [N, D], already T-scaled
    shape_ids: list[str],
    view_counts: tuple[int, ...] = SHARED_SDF_VIEW_COUNTS,
    draws: int = 6,
    n_points: int = 1024,
    seed: int = 0,
) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    """Per view count n (with a shape of >= n views): (|error| [P], variance [P], mean [P]) of the linearised,
    clamped SDF of each shape's views fused n at a time by `rule` (every view alone for n = 1, else `draws`
    random subsets)."""
    groups = []
    for n in view_counts:
        generator = torch.Generator().manual_seed(seed + n)
        parts = []
        for shape_id in dict.fromkeys(shape_ids):
            rows = [i for i, s in enumerate(shape_ids) if s == shape_id]
            if len(rows) < n:
                continue
            subsets = view_subsets(len(rows), n, draws, generator)
            fused = rule(mu[rows][subsets], var[rows][subsets])
            points = sdf_points(world, shape_id, n_points)
            parts.append(
                [t.reshape(-1) for t in clamped_sdf_predictions(predictor.decoder, fused.mu, fused.var, *points)]
            )
        if parts:
            groups.append(tuple(torch.cat(t) for t in zip(*parts)))
    return groups


def decoder_misfit(
    predictor: Predictor,
    world: WorldIndex,
    code: torch.Tensor,  # [N, D] each render's shape's own code
    shape_ids: list[str],
    n_points: int = 1024,
) -> float:
    """RMS of the clamped SDF error of each shape's own code at its ground-truth samples: what the decoder gets
    wrong even at the right code, which no latent variance can express."""
    errors = []
    for shape_id, own in dict(zip(shape_ids, code)).items():
        points, sdf_true = sdf_points(world, shape_id, n_points)
        with frozen(predictor.decoder):
            sdf = code_sdf_fn(predictor.decoder, own)(points)  # the SDF itself: no latent Jacobian is needed
        errors.append(sdf.clamp(-SDF_CLAMP, SDF_CLAMP) - sdf_true.clamp(-SDF_CLAMP, SDF_CLAMP))
    return float(torch.cat(errors).double().square().mean().sqrt())


def shared_sdf_record(
    predictor: Predictor,
    world: WorldIndex,
    fit: SharedError,
    mu: torch.Tensor,  # [N, D]
    var: torch.Tensor,  # [N, D], already T-scaled
    code: torch.Tensor,  # [N, D] each render's shape's own code
    shape_ids: list[str],
) -> dict[str, Any]:
    """The shared rule's fit with its own SDF variance, T var + floor^2 + (b |clamp(mean)|)^2: T and b are fitted
    to the worst calibration error over the val views (var T-scaled) fused 1, 3 and 10 at a time, on all samples
    and near the predicted surface (`fit_sdf_distance_calibration`), and the floor is the decoder's own misfit on
    the val shapes (`decoder_misfit`, measured, not fitted), kept where it lowers that worst error (a decoder
    far from its shapes can have a misfit larger than the fused codes' errors)."""
    rule = SharedErrorFusion(fit.shared_var, fit.view_scale)
    groups = fused_sdf_errors(predictor, world, rule, mu, var, shape_ids)
    counts = [n for n in SHARED_SDF_VIEW_COUNTS if n <= max(shape_ids.count(s) for s in set(shape_ids))]
    misfit = decoder_misfit(predictor, world, code, shape_ids)
    bare, floored = fit_sdf_distance_calibration(groups), fit_sdf_distance_calibration(groups, floor=misfit)
    floor = misfit if floored.worst < bare.worst else None
    chosen = bare if floor is None else floored
    distance = chosen.distance_scale or None
    record = replace(fit, sdf_temperature=chosen.temperature, sdf_floor=floor, sdf_distance_scale=distance).to_record()
    record.update(sdf_view_counts=counts, sdf_calibration_before=chosen.before, sdf_calibration_after=chosen.after)
    record["sdf_calibration_worst"] = chosen.worst
    record["sdf_decoder_misfit"] = misfit
    return record


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
    scaled = apply_temperature(var, temperature)
    shared = None
    if len(set(shape_ids)) < len(shape_ids):  # several views of a shape: what they share can be told apart
        shared = fit_shared_error(mu, scaled, code, shape_ids)
        record["shared_error"] = shared.to_record()
    index = WorldIndex(Path(world), category="", splits={})  # only its per-shape paths are read
    if all(index.sdf_path(s).is_file() for s in set(shape_ids)):  # a real-data world may have no SDF samples
        if shared is not None:
            record["shared_error"] = shared_sdf_record(predictor, index, shared, mu, scaled, code, shape_ids)
        error, std, views = sdf_errors(predictor, index, mu, scaled, shape_ids)
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
