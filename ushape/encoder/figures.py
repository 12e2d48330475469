"""Validation pictures of stage 2: decoded meshes beside their input view (calibration plots: ushape.evaluation)."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from matplotlib.figure import Figure
from torch import Tensor, nn

# A fixed three-quarter view of the normalised cube [-1, 1]^3 for mesh pictures.
MESH_VIEW = {"azimuth_deg": 45.0, "elevation_deg": 25.0, "distance": 3.2, "fov_deg": 40.0}


def render_code(decoder: nn.Module, code: Tensor, resolution: int = 48, image_size: int = 128) -> np.ndarray | None:
    """RGBA uint8 [S, S, 4] of the decoder's mesh for one code [D] from `MESH_VIEW`; None if no surface."""
    from ushape.data.cameras import look_at
    from ushape.data.rendering import render_mesh
    from ushape.decoder.query import code_sdf_fn
    from ushape.mesh.extraction import EmptySurfaceError, extract_mesh

    try:
        mesh, _ = extract_mesh(code_sdf_fn(decoder, code.detach().float()), resolution=resolution, method="dense")
    except EmptySurfaceError:
        return None
    K, world_to_cam = look_at(image_size=image_size, **MESH_VIEW)
    return render_mesh(mesh, K, world_to_cam, image_size)["rgba"]


def mesh_panel(images: Tensor, predicted: Sequence[np.ndarray | None], target: Sequence[np.ndarray | None]) -> Figure:
    """Rows of (input view, mesh of the predicted mean code, mesh of the stage-1 code). images [N, 3, H, W]."""
    n = images.shape[0]
    fig = Figure(figsize=(6, 2 * n), dpi=100)
    axes = fig.subplots(n, 3, squeeze=False)
    for row in range(n):
        panels = (images[row].permute(1, 2, 0).clamp(0, 1).cpu().numpy(), predicted[row], target[row])
        for col, (panel, name) in enumerate(zip(panels, ("input", "mean code", "stage-1 code"))):
            ax = axes[row][col]
            ax.axis("off")
            if row == 0:
                ax.set_title(name, fontsize=9)
            if panel is None:
                ax.text(0.5, 0.5, "no surface", ha="center", va="center", transform=ax.transAxes)
            else:
                ax.imshow(panel)
    fig.tight_layout()
    return fig
