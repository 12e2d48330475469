"""After stage 2, a held-out shape reconstructed with its uncertainty: a run ends with meshes to look at.

For each of the first `shapes` validation shapes, `reconstruct` (the same pipeline as reconstruct.py)
runs once on its first view and once on all its views fused (the `fusion` group's rule, Bayesian by
default), both coloured on the single view's scale so the two can be compared by eye:

    <run>/meshes/<shape id>_1view/     mesh.ply, mesh.glb, overview.png, depth_00.png, summary.json
    <run>/meshes/<shape id>_<N>views/
"""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path
from typing import Callable

from torch import Tensor

from ushape import atomic
from ushape.data.layout import WorldIndex
from ushape.encoder.datamodule import view_files
from ushape.fusion import BayesianFusion, FusedCode
from ushape.mesh.extraction import EmptySurfaceError
from ushape.reconstruction.pipeline import ReconstructionSettings, reconstruct
from ushape.reconstruction.predictor import load_predictor

log = logging.getLogger(__name__)
EMPTY_NOTE = "empty_surface.txt"
FusionRule = Callable[[Tensor, Tensor], FusedCode]  # (mu [V, D], var [V, D]) -> fused Gaussian


def write_demo_meshes(
    checkpoint: str | Path,
    world: WorldIndex,
    out_dir: str | Path,
    shapes: int = 1,
    resolution: int = 96,
    split: str = "val",
    fusion: FusionRule | None = None,
) -> Path | None:
    """Reconstruct `shapes` held-out shapes from 1 and from all views into out_dir; None if shapes = 0.

    A code with no surface (an undertrained encoder) leaves an `empty_surface.txt` saying so, not a crash.
    """
    ids = world.shape_ids(split)[:shapes]
    if shapes <= 0 or not ids:
        return None
    predictor = load_predictor(checkpoint)
    out_dir = Path(out_dir)
    for shape_id in ids:
        views = view_files(world.root, shape_id)
        settings = ReconstructionSettings(resolution=resolution, depth_size=48)
        for inputs in (views[:1], views):
            folder = out_dir / f"{shape_id}_{len(inputs)}view{'s' if len(inputs) > 1 else ''}"
            try:
                summary = reconstruct(predictor, inputs, fusion or BayesianFusion(), folder, settings)
            except EmptySurfaceError as err:
                log.warning("no mesh for %s from %d view(s): %s", shape_id, len(inputs), err)
                folder.mkdir(parents=True, exist_ok=True)
                atomic.write_text(folder / EMPTY_NOTE, f"The fused code's SDF has no zero crossing: {err}\n")
                continue
            # The single view's colour scale for the fused one too: less uncertainty looks darker.
            settings = dataclasses.replace(settings, std_max=float(summary["files"]["std_max"]))
    return out_dir


def demo_digest(meshes_dir: str | Path) -> list[dict]:
    """Per demo reconstruction: its folder name, views fused, latent covariance trace, mean vertex std,
    overview picture; or the empty-surface note. What a run prints at its end."""
    rows = []
    for folder in sorted(p for p in Path(meshes_dir).iterdir() if p.is_dir()):
        record = folder / "summary.json"
        if not record.is_file():
            rows.append({"name": folder.name, "empty": True})
            continue
        summary = json.loads(record.read_text())
        rows.append(
            {
                "name": folder.name,
                "views": len(summary["views"]),
                "trace": summary["fused"]["trace_var"],
                "std_mean": summary["mesh"]["std_mean"],
                "overview": summary["files"]["overview"],
            }
        )
    return sorted(rows, key=lambda row: (row.get("views", 0), row["name"]))  # one view first, then all
