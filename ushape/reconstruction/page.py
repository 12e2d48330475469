"""report.html of one reconstruction (`report_page`): the mesh coloured by its std, fused and refined side by
side where the code was refined, the cameras that are known, the input views and the summary's figures."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
import trimesh

from ushape.reconstruction.export import coloured_mesh
from ushape.reconstruction.report_page import Scene, write_report


def known_cameras(encoded, cameras: Sequence[tuple[np.ndarray, np.ndarray, str]], depth_size: int) -> list[tuple]:
    """(K, world_to_cam, (H, W)) of every view whose camera is known: the refined views' own, else a render's
    (a photo's canonical depth camera is not where the photo was taken, so it is not drawn)."""
    if encoded.refined_views:
        return [(v.K, v.world_to_cam, v.image_hw) for v in encoded.refined_views]
    return [(K, w2c, (depth_size, depth_size)) for K, w2c, kind in cameras if kind == "render"]


def reconstruction_page(
    out_dir: Path,
    encoded,  # pipeline.Encoded
    mesh: trimesh.Trimesh,
    std: np.ndarray,  # [V] the mesh's vertex std
    files: dict[str, Any],  # the mesh's files: colour range ("std_max", "cmap") and colour bar
    cameras: list[tuple],  # known_cameras
    figures: dict[str, Any],
    prior: tuple[trimesh.Trimesh, np.ndarray] | None = None,  # the fused code's mesh and std, where refined
) -> Path:
    """Write report.html for one reconstruction; returns its path."""
    top, cmap = float(files["std_max"]), str(files["cmap"])
    final = "refined" if encoded.refinement is not None and not encoded.refinement.get("fallback") else "fused"
    scenes = [Scene(final, coloured_mesh(mesh, std, top, cmap), cameras)]
    if prior is not None:  # one colour scale for both, so their stds compare
        scenes.insert(0, Scene("fused", coloured_mesh(prior[0], prior[1], top, cmap), cameras))
    views = [image.permute(1, 2, 0).numpy() for image in torch.as_tensor(encoded.images)]
    title = f"{len(views)} view(s), {final}"
    return write_report(out_dir, title, scenes, views, files.get("colour_bar"), figures=figures)


def page_figures(summary_like: dict[str, Any]) -> dict[str, Any]:
    """The figures the page lists under the view, from what summary.json records."""
    keep = {
        "views": len(summary_like.get("views", [])),
        "fusion": summary_like.get("fusion"),
        "latent trace (fused)": summary_like.get("fused", {}).get("trace_var"),
        "mesh vertices": summary_like.get("mesh", {}).get("vertices"),
        "mean vertex std": summary_like.get("mesh", {}).get("std_mean"),
        "seconds": round(sum(summary_like.get("seconds", {}).values()), 2),
    }
    refinement = summary_like.get("refinement")
    if refinement:
        keep["refinement"] = refinement.get("fallback") or f"{refinement.get('mode')}, refined"
    return {k: v for k, v in keep.items() if v is not None}


__all__ = ["known_cameras", "reconstruction_page", "page_figures", "Path"]
