"""One latent code -> SDF grid -> mesh and voxels -> Pix3D metrics against its ground truth, cached by the code's hash.

The prediction is voxelised by its own SDF grid (trilinear, the field marching cubes meshed), so a
reconstruction costs one N^3 decoder pass; the ground truth by its mesh (see metrics).

Many protocol cells decode the same code (Bayesian-10 is Bayesian; a 1.0-crop view is the same
in Tables 3, 4 and 5), so each (decoder, code, resolution, shape) is meshed and scored once; the
scores live in small JSON files, and a rerun of the evaluation decodes nothing it has seen.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
import trimesh
from torch import Tensor

from ushape import atomic
from ushape.data.layout import WorldIndex
from ushape.mesh.extraction import EmptySurfaceError, marching_cubes
from ushape.metrics.pix3d import (
    PIX3D_POINTS,
    PIX3D_VOXELS,
    InsideFn,
    ShapeReference,
    pix3d_metrics,
    reference_from_mesh,
)
from ushape.propagation.field import surface_field

log = logging.getLogger(__name__)

# An empty reconstruction overlaps nothing; CD and EMD have no value.
EMPTY_SCORES = {"iou": 0.0, "cd": math.nan, "emd": math.nan}


def code_hash(decoder_tag: str, code: Tensor, resolution: int, shape_id: str) -> str:
    """Key of one reconstruction: the decoder, the exact code bytes, the mesh resolution and the target shape."""
    digest = hashlib.sha1(f"{decoder_tag}|{resolution}|{shape_id}|".encode())
    digest.update(code.detach().float().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()[:24]


def grid_inside_fn(grid: Tensor) -> InsideFn:
    """Inside test (sdf < 0) by trilinear interpolation of an SDF grid over [-1, 1]^3: the field whose
    zero level set marching cubes meshed, so voxels and mesh agree; outside the cube counts as outside."""
    volume = grid.float()[None, None]  # [1, 1, N, N, N], indexed (x, y, z)

    def inside(points: np.ndarray) -> np.ndarray:
        p = torch.as_tensor(np.asarray(points), dtype=torch.float32)
        # grid_sample's (x, y, z) index the last, middle and first volume axes: reverse ours.
        coords = p.flip(-1).reshape(1, -1, 1, 1, 3)
        sdf = F.grid_sample(volume, coords, mode="bilinear", padding_mode="border", align_corners=True).reshape(-1)
        in_cube = (p.abs() <= 1).all(dim=-1)
        return ((sdf < 0) & in_cube).numpy()

    return inside


class Reconstructor:
    """Meshes and scores codes for one decoder and one world, caching GT references and scores."""

    def __init__(
        self,
        decoder,
        decoder_tag: str,
        world: WorldIndex,
        resolution: int = 64,
        cache_dir: str | Path | None = None,
        voxels: int = PIX3D_VOXELS,
        n_points: int = PIX3D_POINTS,
        bf16: bool = False,
    ) -> None:
        self.decoder, self.decoder_tag, self.world, self.bf16 = decoder, decoder_tag, world, bf16
        self.resolution, self.voxels, self.n_points = resolution, voxels, n_points
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        self._references: dict[str, ShapeReference] = {}
        self._scores: dict[str, dict] = {}
        self.empty = 0  # codes whose mesh had no surface at this resolution (scored IoU 0)

    def reference(self, shape_id: str) -> ShapeReference:
        """The ground truth's normalised voxels and surface points (GT mesh: ray-parity inside test)."""
        if shape_id not in self._references:
            path = self.cache_dir / "gt" / f"{shape_id}_{self.voxels}_{self.n_points}.npz" if self.cache_dir else None
            if path is not None and path.is_file():
                blob = np.load(path)
                ref = ShapeReference(blob["occupancy"], blob["points"])
            else:
                mesh_path = self.world.mesh_path(shape_id)
                if not mesh_path.is_file():
                    raise FileNotFoundError(f"no ground-truth mesh {mesh_path}: the world folder is incomplete")
                ref = reference_from_mesh(trimesh.load(mesh_path, process=False), self.voxels, self.n_points)
                if path is not None:
                    atomic.save_npz(path, occupancy=ref.occupancy, points=ref.points)
            self._references[shape_id] = ref
        return self._references[shape_id]

    def scores(self, code: Tensor, shape_id: str, emd: bool = False) -> dict[str, float]:
        """IoU and CD (and EMD if asked) of the code's mesh against shape_id's ground truth."""
        key = code_hash(f"{self.decoder_tag}|bf16={self.bf16}", code, self.resolution, shape_id)
        cached = self._load(key)
        if cached is not None and (not emd or "emd" in cached):
            return cached
        try:
            # Dense on purpose: a decoder trained on SDFs clamped at 0.1 saturates away from the surface,
            # so coarse-to-fine pruning would evaluate nearly every point anyway, plus its overhead.
            grid = surface_field(self.decoder, code, self.resolution, bf16=self.bf16)
            mesh = marching_cubes(grid)
            result = pix3d_metrics(
                mesh, grid_inside_fn(grid), self.reference(shape_id), emd=emd or (cached or {}).get("emd") is not None
            )
        except EmptySurfaceError:
            result = dict(EMPTY_SCORES)
            self.empty += 1
            if self.empty == 1:  # once per decoder and resolution: the tables count the rest
                log.warning(
                    "the mesh of a code for %s has no surface at %d^3 grid points (parts thinner than a grid step, "
                    "2/%d, vanish) and scores IoU 0: a coarse protocol.resolution lowers every IoU; 64 is the default",
                    shape_id,
                    self.resolution,
                    self.resolution,
                )
        result["empty"] = bool(result["iou"] == 0.0 and math.isnan(result["cd"]))
        self._store(key, result)
        return result

    def _load(self, key: str) -> dict | None:
        if key in self._scores:
            return self._scores[key]
        if self.cache_dir is not None:
            path = self.cache_dir / "scores" / f"{key}.json"
            if path.is_file():
                self._scores[key] = json.loads(path.read_text())
                return self._scores[key]
        return None

    def _store(self, key: str, result: dict) -> None:
        self._scores[key] = result
        if self.cache_dir is not None:
            atomic.write_json(self.cache_dir / "scores" / f"{key}.json", result)
