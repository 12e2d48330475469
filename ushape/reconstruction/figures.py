"""Pictures of a reconstruction: inputs beside the uncertainty-coloured mesh, and per-view depth maps."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402
from torch import Tensor  # noqa: E402

from ushape import atomic  # noqa: E402
from ushape.data.cameras import R2N2_FOV_DEG, look_at  # noqa: E402
from ushape.data.rendering import RayCaster, render_mesh  # noqa: E402
from ushape.propagation.sphere_tracing import DepthStats  # noqa: E402

# The mesh is shown from around the object at the R2N2 elevation, far enough for the unit sphere.
VIEW_AZIMUTHS = (30.0, 120.0, 210.0, 300.0)
VIEW_ELEVATION = 25.0
VIEW_DISTANCE = 2.8
MAX_INPUTS_SHOWN = 10


def mesh_renders(mesh: trimesh.Trimesh, size: int = 192, azimuths: Sequence[float] = VIEW_AZIMUTHS) -> list[np.ndarray]:
    """RGB uint8 [size, size, 3] renders (white background) of a vertex-coloured mesh from each azimuth."""
    caster = RayCaster(mesh)
    renders = []
    for azimuth in azimuths:
        K, w2c = look_at(azimuth, VIEW_ELEVATION, VIEW_DISTANCE, R2N2_FOV_DEG, size)
        rgba = render_mesh(caster, K, w2c, size)["rgba"].astype(np.float32) / 255.0
        renders.append((255 * (rgba[..., :3] + 1.0 - rgba[..., 3:])).round().astype(np.uint8))
    return renders


def _save(fig: plt.Figure, path: str | Path) -> None:
    with atomic.atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight")
    plt.close(fig)


def overview_figure(
    images: Tensor,  # [V, 3, S, S] model inputs
    mesh: trimesh.Trimesh,  # vertex-coloured by std
    path: str | Path,
    std_max: float,
    cmap: str,
    kept: Sequence[int] | None = None,
) -> None:
    """Inputs (fused views marked) on top, the mesh from a few angles below, with a std colour bar."""
    shown = images[:MAX_INPUTS_SHOWN]
    renders = mesh_renders(mesh)
    cols = max(len(shown), len(renders))
    fig, axes = plt.subplots(2, cols, figsize=(2.0 * cols, 4.4), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for i, image in enumerate(shown):
        axes[0, i].imshow(image.permute(1, 2, 0).clamp(0, 1).numpy())
        used = kept is None or i in kept
        axes[0, i].set_title(f"view {i}" + ("" if used else " (dropped)"), fontsize=8, color="k" if used else "r")
    for i, render in enumerate(renders):
        axes[1, i].imshow(render)
        axes[1, i].set_title(f"az {VIEW_AZIMUTHS[i]:.0f}", fontsize=8)
    mappable = plt.cm.ScalarMappable(norm=matplotlib.colors.Normalize(0.0, std_max), cmap=cmap)
    fig.colorbar(mappable, ax=axes[1].tolist(), orientation="horizontal", fraction=0.05, label="SDF std at vertex")
    _save(fig, path)


def depth_figure(image: Tensor, stats: DepthStats, path: str | Path, title: str = "") -> None:
    """One view: its input, the expected depth and its std (implicit or over sampled codes; NaN: no hit)."""
    fig, axes = plt.subplots(1, 3, figsize=(9.6, 3.2))
    axes[0].imshow(image.permute(1, 2, 0).clamp(0, 1).numpy())
    axes[0].set_title(title or "input", fontsize=9)
    # A few pixels on depth edges (codes hitting different parts) would set the std scale alone.
    std = stats.std.numpy()
    top = float(np.nanpercentile(std, 98)) if np.isfinite(std).any() else 1.0
    for ax, data, name, cmap, vmax in (
        (axes[1], stats.mean.numpy(), "expected depth", "viridis", None),
        (axes[2], std, "depth std (98th pct. = top)", "inferno", top or None),
    ):
        shown = ax.imshow(data, cmap=cmap, vmin=0.0 if vmax else None, vmax=vmax)
        ax.set_title(name, fontsize=9)
        fig.colorbar(shown, ax=ax, fraction=0.046)
    for ax in axes:
        ax.axis("off")
    _save(fig, path)
