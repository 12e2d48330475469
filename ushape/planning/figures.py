"""One object's active-reconstruction sequence as a figure: per step, the view taken, the mesh coloured by
its SDF std after fusing it, and the scores over the candidates that chose the next view."""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from ushape.fusion.rules import FusedCode
from ushape.planning.candidates import CandidateViews
from ushape.planning.loop import Step, Surface, surface_of
from ushape.reconstruction.export import colour_range, coloured_mesh
from ushape.reconstruction.figures import mesh_renders

MESH_AZIMUTH = 30.0
MESH_PIXELS = 256  # about the panel's own pixels: at 160 a thin leg or slat falls between the rays and vanishes


def step_surfaces(
    steps: Sequence[Step], decoder, candidates: CandidateViews, resolution: int = 40
) -> list[Surface | None]:
    """The surface after each step (the one the loop computed for the next choice where it did)."""
    surfaces = []
    for k, step in enumerate(steps):
        following = steps[k + 1].surface if k + 1 < len(steps) else None
        if following is None:
            taken = [s.view for s in steps[: k + 1]]
            fused = FusedCode(step.mu, step.var, torch.arange(k + 1))
            following = surface_of(decoder, fused, candidates, taken, resolution)
        surfaces.append(following)
    return surfaces


def sequence_figure(
    inputs: Sequence[torch.Tensor],  # per step, RGB [3, S, S] as the encoder saw the view
    steps: Sequence[Step],
    surfaces: Sequence[Surface | None],
    candidates: CandidateViews,
    ious: Sequence[float],  # per step, the fused code's IoU against the ground truth (NaN: none known)
    heading: str = "",
):
    """A matplotlib Figure: rows = view taken (titled with its pose and the IoU after it), mesh coloured by
    std (one scale for all steps), next-view scores."""
    from matplotlib.figure import Figure

    n = len(steps)
    fig = Figure(figsize=(2.3 * n, 7.2))
    axes = fig.subplots(3, n, squeeze=False)
    stds = [np.sqrt(np.maximum(s.variance, 0)) for s in surfaces if s is not None]
    top = colour_range(np.concatenate(stds)) if stds else 1.0
    angles = candidates.azimuth_elevation()
    for k in range(n):
        axes[0, k].imshow(inputs[k].permute(1, 2, 0).clamp(0, 1).numpy())
        azimuth, elevation = angles[steps[k].view]
        axes[0, k].set_title(f"view {k + 1}: az {azimuth:.0f}, el {elevation:.0f}\nIoU {ious[k]:.3f}", fontsize=8)
        surface = surfaces[k]
        if surface is not None:
            std = np.sqrt(np.maximum(surface.variance, 0))
            render = mesh_renders(coloured_mesh(surface.mesh, std, top), size=MESH_PIXELS, azimuths=(MESH_AZIMUTH,))[0]
            axes[1, k].imshow(render)
            axes[1, k].set_title(f"median std {np.median(std):.3g}", fontsize=8)
        else:
            axes[1, k].set_title("no surface", fontsize=8)
        nxt = steps[k + 1] if k + 1 < n else None
        if nxt is not None and nxt.scores is not None:
            _score_panel(axes[2, k], angles, nxt.scores, [s.view for s in steps[: k + 1]], nxt.view)
        else:
            axes[2, k].set_axis_off()
        for row in (0, 1):
            axes[row, k].set_axis_off()
    axes[2, 0].set_ylabel("next-view score", fontsize=8)
    fig.suptitle(heading + f"  (mesh colour: SDF std, 0 to {top:.3g})", fontsize=9)
    fig.tight_layout()
    return fig


def _score_panel(ax, angles: np.ndarray, scores: np.ndarray, taken: list[int], chosen: int) -> None:
    """Scores against azimuth, a line per elevation (one series where the elevations are scattered, as in
    recorded views); taken views grey, the chosen one red."""
    finite = np.where(np.isfinite(scores), scores, np.nan)
    levels = np.round(angles[:, 1], 1)
    series = [levels == e for e in np.unique(levels)] if len(np.unique(levels)) <= 4 else [np.ones(len(levels), bool)]
    for members in series:
        rows = np.flatnonzero(members)
        rows = rows[np.argsort(angles[rows, 0])]
        ax.plot(angles[rows, 0], finite[rows], marker=".", lw=0.8)
    ax.scatter(angles[taken, 0], finite[taken], color="0.6", zorder=3, s=12)
    ax.scatter([angles[chosen, 0]], [finite[chosen]], color="red", zorder=4, s=18)
    ax.set_xlabel("azimuth (deg)", fontsize=7)
    ax.tick_params(labelsize=6)
