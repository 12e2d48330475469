"""Next view by expected information gain: how much a candidate's observation would shrink the code's Gaussian.

Before a candidate's image exists, its camera and the current shape say which code directions it would
constrain: at the current mean z, the rows its silhouette (and depth) would give have the Jacobian J_c of
`ushape.refinement.residuals`, evaluated on the view the code itself predicts (silhouette rows: J depends
only on the code and the camera; depth rows: the predicted surface points along the candidate's rays;
free-space rows are zero there). With the row weights W of the refinement, the observation would turn
the current covariance Sigma into Sigma' = (Sigma^-1 + J_c^T W J_c)^-1, and the score is the entropy drop

    log det Sigma - log det Sigma' = log det(I + L^T J_c^T W J_c L),   Sigma = L L^T,

in nats (half the change of the Gaussian's differential entropy, times two). Zero for a view that
constrains no direction; a view that pins directions the views taken already pinned gains little, one
that pins a direction nothing constrained yet gains most. It is as informative as Sigma is: on the
refined posterior (full covariance) it knows which directions are pinned; on the paper's fused diagonal
it does not.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch
from torch import Tensor

from ushape.planning.criteria import unseen_uncertain_surface
from ushape.propagation.linearised import latent_jacobian
from ushape.propagation.sphere_tracing import sphere_trace
from ushape.recalibration.refine_information import refined_sdf_temperature
from ushape.refinement.defaults import with_defaults
from ushape.refinement.observation import ObservationSettings, code_functions, residuals, view_rays
from ushape.refinement.posterior import RefineSettings, information_matrix, row_weights
from ushape.refinement.views import ObservedView

PREDICTS = ("masks", "depth")


def information_gain(
    cov: Tensor,  # [D, D] or [D] (diagonal) current covariance of the code
    information: Tensor,  # [D, D] J^T W J of the candidate's predicted rows
) -> float:
    """log det(I + L^T A L) with Sigma = L L^T, A = information: log det Sigma - log det (Sigma^-1 + A)^-1, nats."""
    cov = cov.detach().double()
    cov = torch.diag(cov) if cov.ndim == 1 else 0.5 * (cov + cov.T)
    A = information.detach().double()
    if cov.shape != A.shape or cov.ndim != 2 or cov.shape[0] != cov.shape[1]:
        raise ValueError(f"cov and information must be [D, D] alike, got {tuple(cov.shape)} and {tuple(A.shape)}")
    L = torch.linalg.cholesky(cov)
    M = torch.eye(cov.shape[0], dtype=torch.float64) + L.T @ (0.5 * (A + A.T)) @ L
    return float(2.0 * torch.log(torch.diagonal(torch.linalg.cholesky(M))).sum())


def surface_variance_drop(
    cov: Tensor,  # [D, D] or [D] (diagonal) current covariance of the code
    information: Tensor,  # [D, D] J^T W J of the candidate's predicted rows
    surface_metric: Tensor,  # [D, D] G^T diag(area) G of the current surface's SDF Jacobian G [V, D]
) -> float:
    """sum_v area_v (g_v^T Sigma g_v - g_v^T Sigma' g_v), Sigma' = (Sigma^-1 + A)^-1: how much SDF variance the
    observation would take off the current surface, area-weighted (squared SDF units times area)."""
    cov = cov.detach().double()
    cov = torch.diag(cov) if cov.ndim == 1 else 0.5 * (cov + cov.T)
    A = 0.5 * (information.detach().double() + information.detach().double().T)
    M = surface_metric.detach().double()
    if not (cov.shape == A.shape == M.shape and cov.ndim == 2 and cov.shape[0] == cov.shape[1]):
        raise ValueError(
            f"cov, information and surface_metric must be [D, D] alike, got {tuple(cov.shape)}, "
            f"{tuple(A.shape)} and {tuple(M.shape)}"
        )
    # Sigma - Sigma' = Sigma A^(1/2) (I + A^(1/2) Sigma A^(1/2))^-1 A^(1/2) Sigma, computed without inverting Sigma
    # as Sigma (I + A Sigma)^-1 A Sigma.
    eye = torch.eye(cov.shape[0], dtype=torch.float64)
    drop = cov @ torch.linalg.solve(eye + A @ cov, A @ cov)
    return float((M * drop).sum())


def predicted_view(
    decoder: torch.nn.Module,
    z: Tensor,  # [D]
    K: np.ndarray,  # [3, 3]
    world_to_cam: np.ndarray,  # [4, 4]
    image_hw: tuple[int, int],
    settings: ObservationSettings,
    with_depth: bool,
) -> ObservedView:
    """The view the code z predicts through a camera: its silhouette and, with_depth, its sphere-traced depth at the
    rays the refinement samples (every other pixel has no return), so the predicted rows sit on its own surface."""
    h, w = int(image_hw[0]), int(image_hw[1])
    blank = ObservedView(np.asarray(K, np.float64), np.asarray(world_to_cam, np.float64), torch.zeros(h, w))
    origins, directions, pixels = view_rays(blank, settings)
    sdf, _ = code_functions(decoder, z.detach().float())
    t, hit = sphere_trace(
        lambda x, _code: sdf(x), origins, directions, 1, settings.trace_steps, settings.trace_eps, settings.bound
    )
    mask = torch.zeros(h * w)
    mask[pixels[hit[0]]] = 1.0
    depth = None
    if with_depth:
        depth = torch.zeros(h * w)
        depth[pixels[hit[0]]] = t[0, hit[0]]  # camera-z component of the directions is 1: t is the depth
        depth = depth.reshape(h, w)
    return replace(blank, mask=mask.reshape(h, w), depth=depth)


def candidate_information(
    decoder: torch.nn.Module,
    z: Tensor,  # [D]
    K: np.ndarray,
    world_to_cam: np.ndarray,
    image_hw: tuple[int, int],
    settings: RefineSettings,
) -> Tensor:  # [D, D]
    """J_c^T W J_c of the rows a view through this camera would add, predicted at code z (mode masks or depth)."""
    if settings.mode not in PREDICTS:
        raise ValueError(f"the predicted observation must be one of {PREDICTS}, got {settings.mode!r}")
    with_depth = settings.mode == "depth"
    view = predicted_view(decoder, z, K, world_to_cam, image_hw, settings.observation, with_depth)
    res = residuals(decoder, z.detach().float(), [view], settings.observation, with_depth)
    return settings.information_scale * information_matrix(res, row_weights(res, settings))


class InformationGain:
    """Each open candidate scored by `information_gain` of the rows it would add, at the current Gaussian.

    mode: what a view would be compared on, masks or depth; None: as the loop observes (masks where it
    observes nothing, so the paper's fused Gaussian is scored on the silhouettes a view would give).
    """

    name = "information"
    predicts_rows = True  # scored on the rows a view would add, predicted at the current mean

    def __init__(
        self,
        mode: str | None = None,
        size: int | None = None,
        sigma_mask: float | None = None,
        sigma_depth: float | None = None,
    ) -> None:
        size, sigma_mask, sigma_depth = (
            with_defaults(size=size, sigma_mask=sigma_mask, sigma_depth=sigma_depth)[k]
            for k in ("size", "sigma_mask", "sigma_depth")
        )
        if mode is not None and mode not in PREDICTS:
            raise ValueError(f"information mode must be one of {PREDICTS} or None, got {mode!r}")
        if size < 1:
            raise ValueError(f"size (rays per image side) must be >= 1, got {size}")
        self.mode, self.size, self.sigma_mask, self.sigma_depth = mode, size, sigma_mask, sigma_depth

    @classmethod
    def for_sequence(cls, context, **settings):
        """The sequence's rays per side (the refinement's), unless the settings give them."""
        return cls(**{"size": context.size, **settings})

    def settings(self, observes: str) -> RefineSettings:
        mode = self.mode or ("depth" if observes == "depth" else "masks")
        observation = ObservationSettings(size=self.size)
        return RefineSettings(
            mode=mode, sigma_mask=self.sigma_mask, sigma_depth=self.sigma_depth, observation=observation
        )

    def scores(self, state) -> np.ndarray:  # state: ushape.planning.loop.PlanState
        settings = self.settings(state.observes)
        candidates, fused = state.candidates, state.fused
        scores = np.zeros(len(candidates))
        hws = candidates.image_hw
        for c in range(len(candidates)):
            if c in state.taken:
                continue
            A = candidate_information(
                state.decoder, fused.mu, candidates.K[c], candidates.world_to_cam[c], tuple(hws[c]), settings
            )
            scores[c] = information_gain(fused.var, A)
        return scores


class SurfaceInformationGain(InformationGain):
    """Each open candidate scored by the SDF variance its predicted rows would take off the current surface
    (`surface_variance_drop`), each vertex weighted by the area it stands for.

    The log-det score counts every code direction alike, relative to its own variance; this one counts a
    direction by how much the decoder turns it into surface, in SDF units. Where the current mean has no
    surface, the log-det score is used.
    """

    name = "information-surface"

    def scores(self, state) -> np.ndarray:  # state: ushape.planning.loop.PlanState
        surface = state.surface
        if surface is None:
            return super().scores(state)
        vertices = torch.as_tensor(np.asarray(surface.mesh.vertices), dtype=torch.float32)
        _, G = latent_jacobian(state.decoder, state.fused.mu.float(), vertices)
        G = G.double()
        metric = G.T @ (torch.as_tensor(surface.area, dtype=torch.float64)[:, None] * G)
        settings, candidates = self.settings(state.observes), state.candidates
        scores = np.zeros(len(candidates))
        for c in range(len(candidates)):
            if c in state.taken:
                continue
            A = candidate_information(
                state.decoder,
                state.fused.mu,
                candidates.K[c],
                candidates.world_to_cam[c],
                tuple(candidates.image_hw[c]),
                settings,
            )
            scores[c] = surface_variance_drop(state.fused.var, A, metric)
        return scores


def seen_floor_drop(
    visible: np.ndarray,  # [C, V] bool: candidate c would see vertex v
    seen: np.ndarray,  # [V] bool: a view taken sees vertex v
    area: np.ndarray,  # [V] the surface each vertex stands for
    floor_seen: float,
    floor_unseen: float,
) -> np.ndarray:  # [C]
    """sum_v area_v (floor_unseen^2 - floor_seen^2) over the vertices candidate c would see that no view taken
    sees: the SDF variance the floors of the refined posterior would lose there (`refine_calibration`'s seen
    model: the error the decoder's code cannot carry, pinned where a view saw the surface)."""
    gap = np.full(len(area), floor_unseen**2 - floor_seen**2)  # the variance a first sight takes off each vertex
    return unseen_uncertain_surface(np.asarray(visible, bool), gap, area, seen)


class SeenInformationGain(SurfaceInformationGain):
    """`SurfaceInformationGain` on the refined posterior's SDF variance as the mesh is drawn with a fitted seen
    model, T g^T Sigma g + floor^2 (floor_seen where a view taken sees the vertex, floor_unseen elsewhere): a
    candidate's score is T times the variance its predicted rows take off the code's part, plus what its first
    sight of unseen surface takes off the floors (`seen_floor_drop`). floors: {"sdf_temperature", "floor_seen",
    "floor_unseen"} of a run's `reconstruct.py --fit-refinement` fit."""

    name = "information-seen"

    def __init__(self, floors: dict | None = None, **options) -> None:
        if floors is None or not all(k in floors for k in ("sdf_temperature", "floor_seen", "floor_unseen")):
            raise ValueError(
                "information-seen needs the run's fitted seen model: run `reconstruct.py --fit-refinement "
                "masks|depth --run RUN` first (it stores refinement_calibration.json beside the checkpoint)"
            )
        super().__init__(**options)
        self.floors = floors

    @classmethod
    def for_sequence(cls, context, **settings):
        """The floors of the predictor's run's seen model, fitted for what the loop observes (masks where it
        observes nothing), unless the settings give them."""
        if "floors" not in settings and context.predictor is not None:
            from ushape.reconstruction.refine_calibration import seen_model

            observes = getattr(context.observer, "name", "none")
            settings["floors"] = seen_model(context.predictor.checkpoint, observes)
        return super().for_sequence(context, **settings)

    def scores(self, state) -> np.ndarray:  # state: ushape.planning.loop.PlanState
        surface = state.surface
        latent = super().scores(state)
        if surface is None:
            return latent
        f = self.floors
        temperature = refined_sdf_temperature(f, len(state.taken) + 1)  # at the views once the candidate is taken
        return temperature * latent + seen_floor_drop(
            surface.visible, surface.seen, surface.area, f["floor_seen"], f["floor_unseen"]
        )
