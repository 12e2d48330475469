"""A few reconstructions with their uncertainty, saved for people to look at (the notebook shows them).

For the first shapes of the evaluation, each encoder's single-view (view 0) and fused (Bayesian,
or average for FroDO*) reconstructions are saved as <label>_<shape>_<kind>.npz (vertices, faces,
per-vertex SDF std by Monte Carlo) and as a PNG coloured by that std (blue: sure, red: unsure).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import trimesh

from ushape import atomic
from ushape.data.cameras import look_at
from ushape.data.rendering import on_white, render_mesh
from ushape.evaluation.protocols import group_views
from ushape.fusion.rules import fuse_average, fuse_bayesian
from ushape.mesh.extraction import EmptySurfaceError
from ushape.mesh.preview import PREVIEW_VIEW
from ushape.propagation import vertex_uncertainty
from ushape.propagation.field import code_mesh

SHOWCASE_DIR = "meshes"


@dataclass
class Showcase:
    """What an evaluation saves for people to look at (conf/eval.yaml's `showcase`): the first `shapes` test
    shapes' reconstructions (0: none), their per-vertex std from `mc_samples` Monte Carlo codes."""

    shapes: int = 2
    mc_samples: int = 10

    def __post_init__(self) -> None:
        if self.shapes < 0 or self.mc_samples < 2:
            raise ValueError(f"showcase.shapes must be >= 0 and showcase.mc_samples >= 2, got {self}")


def uncertainty_colours(std: np.ndarray, vmax: float | None = None) -> np.ndarray:
    """Per-value RGB [N, 3] in [0, 1] from a blue (0) to red (vmax, default the 95th percentile) ramp."""
    std = np.asarray(std, dtype=np.float64)
    vmax = float(np.percentile(std, 95)) if vmax is None else vmax
    t = np.clip(std / vmax, 0.0, 1.0) if vmax > 0 else np.zeros_like(std)
    return np.stack([t, 0.25 * (1 - np.abs(2 * t - 1)), 1 - t], axis=-1)


def render_uncertainty(mesh: trimesh.Trimesh, std: np.ndarray, image_size: int = 192) -> np.ndarray:
    """RGB uint8 [S, S, 3] of the mesh from the preview view, each face coloured by its vertices' mean std."""
    face_colours = uncertainty_colours(np.asarray(std)[mesh.faces].mean(axis=1))
    rgba = render_mesh(
        mesh,
        *look_at(image_size=image_size, **PREVIEW_VIEW),
        image_size,
        colour_fn=lambda points, face: face_colours[face],
    )["rgba"]
    return on_white(rgba)


def save_showcase(
    run,
    encodings,
    out_dir: str | Path,
    group_size: int,
    n_shapes: int = 2,
    resolution: int = 64,
    n_samples: int = 10,
    seed: int = 0,
) -> list[Path]:
    """Save single-view and fused reconstructions with per-vertex std for the first n_shapes; returns the PNGs.

    The Monte Carlo codes are drawn from a generator seeded with `seed`, so the pictures do not depend on what
    the evaluation drew from torch's global generator before them (which protocols ran, in which order)."""
    from PIL import Image

    out = Path(out_dir) / SHOWCASE_DIR
    decoder = run.predictor.decoder
    fuse = fuse_bayesian if run.spec.probabilistic else fuse_average
    written = []
    first_groups = {}
    for group in group_views(encodings.keys, group_size):
        first_groups.setdefault(group[0].shape_id, group)
    for group in list(first_groups.values())[:n_shapes]:
        mu, var = encodings.select(group)
        fused = fuse(mu, var)
        for kind, (code, code_var) in {"single": (mu[0], var[0]), "fused": (fused.mu, fused.var)}.items():
            try:
                mesh, _ = code_mesh(decoder, code, resolution)
            except EmptySurfaceError:
                continue
            vertices = mesh.vertices.astype(np.float32)
            draws = torch.Generator().manual_seed(seed)
            std = vertex_uncertainty(
                decoder, code, code_var, torch.from_numpy(vertices), "mc", n_samples, generator=draws
            ).numpy()
            stem = re.sub(r"[^A-Za-z0-9_.-]", "", f"{run.spec.label}_{group[0].shape_id}_{kind}")
            atomic.save_npz(out / f"{stem}.npz", vertices=vertices, faces=mesh.faces, std=std)
            png = out / f"{stem}.png"
            with atomic.atomic_path(png) as tmp:
                Image.fromarray(render_uncertainty(mesh, std)).save(tmp, format="PNG")
            written.append(png)
    return written
