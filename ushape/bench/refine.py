"""Wall-clock cost of refining one object's code on its views, to set beside extracting its mesh with uncertainty,
and of refining it with the object's pose hidden (pose and shape together, `ushape.refinement.joint`) from its
first view and from its first three with their relative motion, each beside the known-camera refinement of the
same views (the ratio in the note).

The views: `views` cameras on the depth rows' orbit (`depth.orbit_cameras`) at `size` px. What they
show is the benched code's own surface (the mean code's trace: hit = mask, its depth), and the
refinement starts from a prior 0.1 std away from it, as a fused code from the encoder would. The
refinement compares `rays` rays per image side (reconstruct.py's --refine-size).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from ushape.bench.depth import orbit_cameras
from ushape.bench.timing import Measurement, timed
from ushape.propagation.depth_implicit import depth_uncertainty_implicit_views
from ushape.refinement import ObservationSettings, ObservedView, RefineSettings, refine
from ushape.refinement.joint import PoseGroups, PoseSettings
from ushape.refinement.pose_search import refine_pose_and_shape


def code_views(decoder: nn.Module, code: Tensor, views: int, size: int) -> list[ObservedView]:  # code [D]
    """The code's own silhouette and depth seen by `views` orbit cameras at size x size px."""
    cameras = orbit_cameras(views, size)
    stats = depth_uncertainty_implicit_views(decoder, code, torch.zeros_like(code), cameras, (size, size))
    return [
        ObservedView(K, w2c, s.hit_rate.float(), torch.nan_to_num(s.mean, nan=0.0))
        for (K, w2c), s in zip(cameras, stats)
    ]


def displaced_prior(code: Tensor, seed: int) -> tuple[Tensor, Tensor]:  # code [D] -> mu [D], var [D]
    """The prior the bench refines from: 0.1 std (var 0.01 a dimension) away from the code, as a fused code would be."""
    return code + 0.1 * torch.randn(code.shape, generator=torch.Generator().manual_seed(seed)), torch.full_like(
        code, 0.01
    )


def refine_rows(
    decoder: nn.Module,
    code: Tensor,  # [D]
    views: int = 12,
    size: int = 64,
    rays: int = 32,
    seed: int = 0,
    repeats: int = 1,
) -> list[Measurement]:
    """Rows "refine masks (<views> views, <size> px)" and "refine depth (...)", each noting its iterations."""
    observed = code_views(decoder, code, views, size)
    prior_mu, prior_var = displaced_prior(code, seed)
    rows = []
    for mode in ("masks", "depth"):
        settings = RefineSettings(mode=mode, observation=ObservationSettings(size=rays))
        seconds, post = timed(lambda: refine(decoder, prior_mu, prior_var, observed, settings), repeats)
        note = f"{post.iterations} iterations, {rays} rays per side, fallback: {post.fallback}"
        rows.append(Measurement(f"refine {mode} ({views} views, {size} px)", seconds, repeats, note=note))
    return rows


def pose_rows(
    decoder: nn.Module,
    code: Tensor,  # [D]
    views: int = 12,
    size: int = 64,
    rays: int = 32,
    seed: int = 0,
    repeats: int = 1,
    pose_settings: PoseSettings = PoseSettings(),
) -> list[Measurement]:
    """Rows "refine masks, pose estimated (<n> of <views> views, <size> px)" for n = 1 and 3, with the known-camera
    refinement of the same views and the ratio between them in the note."""
    observed = code_views(decoder, code, views, size)
    prior_mu, prior_var = displaced_prior(code, seed)
    settings = RefineSettings(mode="masks", observation=ObservationSettings(size=rays))
    rows = []
    for n in (1, 3):
        chosen = observed[:: max(1, len(observed) // n)][:n]
        known, _ = timed(lambda: refine(decoder, prior_mu, prior_var, chosen, settings), repeats)
        groups = PoseGroups.from_cameras([v.world_to_cam for v in chosen])
        seconds, post = timed(
            lambda: refine_pose_and_shape(decoder, prior_mu, prior_var, chosen, groups, settings, pose_settings),
            repeats,
        )
        note = f"{seconds / known:.1f}x the known cameras' {known:.2f} s; {post.iterations} final-stage iterations"
        rows.append(Measurement(f"refine masks, pose estimated ({n} of {views} views, {size} px)", seconds, repeats,
                                note=note))  # fmt: skip
    return rows
