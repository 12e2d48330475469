"""Calibrate the refined posterior on val shapes, per refinement mode, and keep the fit beside the checkpoint.

The refinement's Laplace posterior counts every ray as an independent observation and the decoder cannot
draw the true shape, so its covariance is too narrow, more so as views add up (docs/refinement.md). Two
fits on the val split correct it, each by what it is scored on:
  - latent: the information scale s of (Sigma^-1 + s J^T W J)^-1, by the calibration error of the refined
    codes against the shapes' own codes (`refine_information.fit_information_scale`);
  - SDF: the factor, its growth with the views and the floor of the SDF variance propagated from that
    posterior, T_sdf n^beta var + floor^2 (floor between 0 and the decoder's own misfit), by the worst
    calibration error over the val shapes refined on n = 1, 3 and 10 views, at the samples where the refined
    SDF is within the clamp (`refine_information.fit_sdf_recalibration`); used where the points' visibility is
    not known (eval.py's tables);
  - SDF where a view saw the point and where none did: the same variance with two floors, fitted so that the
    seen and the unseen points are each calibrated (`refine_information.fit_sdf_recalibration_seen`; a point
    is seen when an observed pixel shows it and the refined mesh does not hide it,
    `visibility.seen_by_views`); reconstruct.py's mesh std applies it.
The prior refined is the run's default fusion of the views (`shared` where --fit-temperature fitted it),
as reconstruct.py refines it. `refinement_calibration.json` = {mode: {"information_scale", "sdf_temperature",
"sdf_view_exponent", "sdf_floor", "latent_calibration_before", "latent_calibration_after", "sdf_calibration_before",
"sdf_calibration_after", "sdf_decoder_misfit", "seen", "view_counts", "n_shapes", "size", "fusion", "fallbacks"}},
"seen" = {"sdf_temperature", "sdf_view_exponent", "floor_seen", "floor_unseen", "sdf_calibration_after",
"seen_after", "unseen_after", "seen_fraction", "tolerance"}.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
import trimesh

from ushape import atomic
from ushape.data.layout import WorldIndex, read_split
from ushape.data.sdf_dataset import sdf_points
from ushape.decoder.artifacts import codes_file, load_codes
from ushape.decoder.query import code_sdf_fn, frozen
from ushape.encoder.datamodule import view_files
from ushape.mesh.extraction import EmptySurfaceError, extract_mesh
from ushape.propagation import SDF_CLAMP, clamped_sdf_predictions
from ushape.recalibration.refine_information import (
    VIEW_EXPONENT_GRID,
    fit_information_scale,
    fit_sdf_recalibration,
    fit_sdf_recalibration_seen,
)
from ushape.reconstruction.calibrated_fusion import default_fusion
from ushape.reconstruction.predictor import Predictor
from ushape.reconstruction.temperature_store import decoder_misfit
from ushape.reconstruction.visibility import SEEN_TOLERANCE, seen_by_views
from ushape.refinement import ObservationSettings, RefineSettings, refine
from ushape.refinement.inputs import input_views
from ushape.refinement.posterior import prior_precision
from ushape.workspace import CALIBRATION_FILE

# How many of a val shape's views the refinement is fitted on at a time (Table V's counts).
VIEW_COUNTS = (1, 3, 10)
# Val shapes the fit refines (all where fewer). On 4 the fitted s scattered over 1e-4-0.1 and its test
# calibration missed; on 20 it held on the test shapes (docs/refinement.md, "How many val shapes").
FIT_SHAPES = 20
# The refined code's mesh, on which a point's visibility from the views is decided.
MESH_RESOLUTION = 64


def spread_views(n_views: int, n: int) -> list[int] | None:
    """n of a shape's n_views views spread evenly around its orbit (12 views, 3: 0, 4, 8), None if n > n_views."""
    return None if n > n_views else sorted({int(i * n_views / n) for i in range(n)})


def calibration_path(checkpoint: str | Path) -> Path:
    return Path(checkpoint).parent / CALIBRATION_FILE


def read_refinement_calibration(checkpoint: str | Path, mode: str) -> dict[str, Any] | None:
    """The fit `fit_and_store_refinement_calibration` stored for this mode beside the checkpoint, or None."""
    path = calibration_path(checkpoint)
    if not path.is_file():
        return None
    return stored_calibration(path).get(mode)


def stored_calibration(path: Path) -> dict[str, Any]:
    """Every mode's fit in refinement_calibration.json; a damaged file is named, with what to do."""
    return atomic.read_json_object(
        path, "move it aside and refit each mode with `python reconstruct.py --fit-refinement masks|depth --run RUN`"
    )


def seen_model(checkpoint: str | Path, observes: str) -> dict[str, Any]:
    """The seen model ({"sdf_temperature", "floor_seen", "floor_unseen", ...}) fitted for the mode a view is
    refined on (masks where nothing is: the silhouette is what a view would add), with its information scale."""
    mode = "depth" if observes == "depth" else "masks"
    fit = read_refinement_calibration(checkpoint, mode)
    if fit is None or not fit.get("seen"):
        raise ValueError(
            f"no seen model fitted for {mode} beside {checkpoint}: run `reconstruct.py --fit-refinement {mode} "
            "--run RUN` (a fit stored before the seen model has none: refit it)"
        )
    return {**fit["seen"], "information_scale": fit["information_scale"]}


def refined_val_shapes(
    predictor: Predictor, world: WorldIndex, codes, fusion, settings: RefineSettings, n_shapes: int, n_points: int
) -> tuple[list[dict], int, list[str]]:
    """Per refined (val shape, view set): n, |z* - z_own| [D], the prior precision and J^T W J [D, D], the SDF
    samples and which of them the views saw; with the number that fell back (left out) and the shapes used.
    codes: the val shapes' own codes; fusion: the rule that makes each prior."""
    shapes = world.shape_ids("val")[:n_shapes]
    refined, fallbacks = [], 0
    for shape_id in shapes:
        files = view_files(world.root, shape_id)
        images, _, _ = predictor.load_images(files, reframe=False)  # the world's renders, as evaluated
        mu, var = predictor.encode(images)
        points, sdf_true = sdf_points(world, shape_id, n_points)
        for n in VIEW_COUNTS:
            chosen = spread_views(len(files), n)
            if chosen is None:
                continue
            fused = fusion(mu[chosen], var[chosen])
            views = input_views([Path(files[i]) for i in chosen])  # as reconstruct.py reads a render's views
            post = refine(predictor.decoder, fused.mu, fused.var, views, settings)
            if post.fallback is not None or post.information is None:
                fallbacks += 1
                continue
            refined.append(
                {
                    "n": n,
                    "mu": post.mu,
                    "error": post.mu - codes.lookup(shape_id),
                    "precision": prior_precision(fused.var),
                    "information": post.information,
                    "sdf": (points, sdf_true),
                    "seen": torch.as_tensor(seen_by_views(refined_mesh(predictor.decoder, post.mu), points, views)),
                }
            )
    return refined, fallbacks, shapes


def refined_mesh(decoder, code: torch.Tensor) -> trimesh.Trimesh:
    """The mesh of a refined code, at which its points' visibility is decided (empty where it has no surface:
    nothing then hides a point)."""
    try:
        with frozen(decoder):
            mesh, _ = extract_mesh(code_sdf_fn(decoder, code), MESH_RESOLUTION)
    except EmptySurfaceError:
        return trimesh.Trimesh()
    return mesh


def sdf_groups(
    decoder, refined: list[dict], scale: float
) -> list[tuple[int, torch.Tensor, torch.Tensor, torch.Tensor]]:
    """Per view count: (n, |SDF error| [P], std [P], seen [P]) of the posteriors at information scale s, linearised
    and clamped as the evaluation propagates them, at the samples where the refined SDF is within the clamp.

    Beyond the clamp the linearised prediction is a point mass at +-clamp (no variance): no factor changes its
    interval, and those samples, covered at every level where the truth is clamped too (most of them), would
    pull the factor down to offset them (measured on the tables model's 20 val tables: test SDF calibration
    error at 10 views 0.084 fitted on every sample, 0.069 on those within the clamp; docs/refinement_probes.md).
    """
    groups = []
    for n in VIEW_COUNTS:
        errors, stds, seen = [], [], []
        for r in (r for r in refined if r["n"] == n):
            cov = torch.linalg.inv(r["precision"] + scale * r["information"].double()).float()
            e, var, mean = clamped_sdf_predictions(decoder, r["mu"][None], cov[None], *r["sdf"])
            inside = mean.reshape(-1).abs() < SDF_CLAMP
            errors.append(e.reshape(-1)[inside]), stds.append(var.reshape(-1)[inside].sqrt())
            seen.append(r["seen"].reshape(-1)[inside])
        if errors and sum(len(e) for e in errors):
            groups.append((n, torch.cat(errors), torch.cat(stds), torch.cat(seen)))
    return groups


def fit_refinement_calibration(
    predictor: Predictor,
    mode: str,
    world: str | Path | None = None,
    n_shapes: int = FIT_SHAPES,
    size: int = 24,
    n_points: int = 1024,
) -> dict[str, Any]:
    """Refine the first n_shapes val shapes on 1, 3 and 10 of their views, fit s and the SDF (T_sdf, floor)."""
    if n_shapes < 1:
        raise ValueError(f"the fit needs at least 1 val shape (--fit-shapes), got {n_shapes}")
    world = world or predictor.world
    if world is None:
        raise ValueError("which world's val split? pass a run folder (its run.json names the world) or `world=`")
    index = WorldIndex(Path(world), category="", splits={"val": read_split(world, "val")})  # the val split's paths
    settings = RefineSettings(mode=mode, observation=ObservationSettings(size=size))
    codes = load_codes(Path(predictor.model.hparams.decoder_path) / codes_file("val"))
    fusion = default_fusion(predictor)
    refined, fallbacks, shapes = refined_val_shapes(predictor, index, codes, fusion, settings, n_shapes, n_points)
    if not refined:
        raise ValueError(f"no val shape of {world} could be refined ({fallbacks} fell back): nothing to fit")
    scale, latent_before, latent_after = fit_information_scale(
        [r["error"] for r in refined], [r["precision"] for r in refined], [r["information"] for r in refined]
    )
    misfit = decoder_misfit(predictor, index, torch.stack([codes.lookup(s) for s in shapes]), shapes, n_points)
    groups = sdf_groups(predictor.decoder, refined, scale)
    counts = [n for n, *_ in groups]
    plain = fit_sdf_recalibration(
        [(e, s) for _, e, s, _ in groups], misfit, view_counts=counts, exponents=VIEW_EXPONENT_GRID
    )
    seen = fit_sdf_recalibration_seen([g[1:] for g in groups], misfit, view_counts=counts, exponents=VIEW_EXPONENT_GRID)
    return {
        "information_scale": scale,
        "latent_calibration_before": latent_before,
        "latent_calibration_after": latent_after,
        "sdf_temperature": plain.temperature,
        "sdf_view_exponent": plain.view_exponent,
        "sdf_floor": plain.floor,
        "sdf_calibration_before": plain.before,
        "sdf_calibration_after": plain.after,
        "sdf_decoder_misfit": misfit,
        "seen": {
            "sdf_temperature": seen["sdf_temperature"],
            "sdf_view_exponent": seen["sdf_view_exponent"],
            "floor_seen": seen["floor_seen"],
            "floor_unseen": seen["floor_unseen"],
            "sdf_calibration_after": seen["after"],
            "seen_after": seen["after_seen"],
            "unseen_after": seen["after_unseen"],
            "seen_fraction": [float(s.float().mean()) for *_, s in groups],
            "tolerance": SEEN_TOLERANCE,
        },
        "view_counts": sorted({r["n"] for r in refined}),
        "n_shapes": len(shapes),
        "size": size,
        "fusion": type(fusion).__name__,
        "fallbacks": fallbacks,
    }


def fit_and_store_refinement_calibration(predictor: Predictor, mode: str, **options) -> dict[str, Any]:
    """Fit this mode's calibration and write it into refinement_calibration.json beside the checkpoint (the
    other mode's fit is kept); returns the fit."""
    path = calibration_path(predictor.checkpoint)
    stored = stored_calibration(path) if path.is_file() else {}  # read before the fit: a damaged file stops it now
    record = fit_refinement_calibration(predictor, mode, **options)
    stored = stored_calibration(path) if path.is_file() else {}  # again: another fit may have written it since
    stored[mode] = record
    atomic.write_json(path, stored)
    return record
