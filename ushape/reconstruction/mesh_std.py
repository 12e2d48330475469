"""The std drawn on the mesh: the meshed code's variance propagated to the vertices, with the SDF calibration
that applies to that code (a refinement's --fit-refinement fit, with its floors where the views saw the surface
and where they did not; else the fusion rule's own; else the predictor's single-view one)."""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch
import trimesh
from torch import Tensor

from ushape.fusion.rules import FusedCode
from ushape.propagation.mesh import vertex_uncertainty
from ushape.recalibration import apply_temperature
from ushape.recalibration.refine_information import refined_sdf_temperature, seen_floor_variance
from ushape.reconstruction.predictor import Predictor
from ushape.reconstruction.settings import ReconstructionSettings
from ushape.reconstruction.visibility import seen_by_views
from ushape.refinement import ObservedView

Fusion = Callable[[Tensor, Tensor], FusedCode]  # (mu [V, D], var [V, D]) -> FusedCode (var [D] or [D, D])


def sdf_temperature(fusion: Fusion, predictor: Predictor, refinement: dict | None = None) -> float | None:
    """The factor on the SDF variance propagated from the code meshed: a refined code's, the refinement's own
    where --fit-refinement fitted it (`refinement["calibration"]`, at the number of views refined on); a fused
    code's, the fusion rule's own where it has one (`shared`, fitted on val on its fused variance); else the
    predictor's single-view one."""
    if refinement is not None:
        calibration, floors = refinement.get("calibration"), seen_floors(refinement)
        n_views = max(1, int(refinement.get("views_refined") or 1))  # the fit's factor may grow with the views
        if floors is not None:  # fitted with the seen / unseen floors, as the mesh's std is drawn
            return refined_sdf_temperature(floors, n_views)
        return predictor.sdf_temperature if calibration is None else refined_sdf_temperature(calibration, n_views)
    own = getattr(fusion, "sdf_temperature", None)
    return predictor.sdf_temperature if own is None else own


def seen_floors(refinement: dict | None) -> dict | None:
    """The refinement's fitted variance with its floors where the views saw the surface and where they did not
    (`refine_calibration`'s "seen"), or None: no refinement, a fallback to the prior, or a fit stored before it."""
    if refinement is None or refinement.get("fallback") is not None:
        return None
    return (refinement.get("calibration") or {}).get("seen")


def sdf_floor(fusion: Fusion, refinement: dict | None = None) -> float | None:
    """The std added to that SDF variance, T var + floor^2: the refinement's fitted floor, or the fusion rule's;
    None where the refinement's seen / unseen floors differ per vertex (they are in the mesh's std)."""
    if refinement is not None:
        if seen_floors(refinement) is not None:
            return None
        return (refinement.get("calibration") or {}).get("sdf_floor") or None
    return getattr(fusion, "sdf_floor", None)


def sdf_distance_scale(fusion: Fusion, refinement: dict | None = None) -> float | None:
    """b in the fusion rule's SDF variance T var + floor^2 + (b |mean|)^2 (`shared`, fitted on val); None for a
    refined code (its fit has no distance term) or a rule without one. The mesh's std files leave the term out:
    at the mesh's vertices the mean SDF is 0 up to the marching-cubes interpolation, so it adds ~nothing there."""
    return None if refinement is not None else getattr(fusion, "sdf_distance_scale", None)


def mesh_std(
    predictor: Predictor,
    fusion: Fusion,
    fused: FusedCode,  # the code meshed: fused, or refined (var [D, D]) on `views`
    mesh: trimesh.Trimesh,
    settings: ReconstructionSettings,  # its uncertainty method and Monte Carlo codes
    generator: torch.Generator,
    refinement: dict | None = None,  # the refinement's record (refined_code.refined), None: not refined
    views: list[ObservedView] = (),  # the views refined on (their visibility decides the seen floors)
    bf16: bool = False,
) -> np.ndarray:
    """The calibrated SDF std [V] at the mesh's vertices; where the refinement's seen floors apply, the record
    gains `seen_vertices`, the fraction of vertices a refined view saw."""
    vertices = torch.as_tensor(np.asarray(mesh.vertices), dtype=torch.float32)
    std = vertex_uncertainty(
        predictor.decoder, fused.mu, fused.var, vertices, settings.uncertainty, settings.n_samples, generator, bf16=bf16
    )
    floors = seen_floors(refinement)
    sdf_t = sdf_temperature(fusion, predictor, refinement)
    if floors is not None:  # the refinement's fit with a floor where the views saw the surface, one where not
        seen = torch.as_tensor(seen_by_views(mesh, mesh.vertices, views, floors["tolerance"]))
        variance = seen_floor_variance(std.double().square(), seen, sdf_t, floors["floor_seen"], floors["floor_unseen"])
        std = variance.sqrt().float()
        refinement["seen_vertices"] = float(seen.float().mean()) if len(seen) else None
    elif sdf_t is not None:  # the SDF-space recalibration (`fit_and_store_temperature`)
        std = apply_temperature(std.square(), sdf_t).sqrt()
    return std.numpy()
