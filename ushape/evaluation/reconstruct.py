"""One latent code -> mesh -> Pix3D metrics against its ground truth, cached by the code's hash.

Many protocol cells decode the same code (Bayesian-10 is Bayesian; a 1.0-crop view is the same
in Tables 3, 4 and 5), so each (decoder, code, resolution, shape) is meshed and scored once; the
scores live in small JSON files, and a rerun of the evaluation decodes nothing it has seen.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import torch
import trimesh
from torch import Tensor

from ushape import atomic
from ushape.data.layout import WorldIndex
from ushape.evaluation.metrics import PIX3D_POINTS, PIX3D_VOXELS, ShapeReference, pix3d_metrics, reference_from_mesh
from ushape.mesh.extraction import EmptySurfaceError, extract_mesh
from ushape.metrics.reconstruction import sdf_inside_fn
from ushape.propagation import decode_points, frozen

# An empty reconstruction overlaps nothing; CD and EMD have no value.
EMPTY_SCORES = {"iou": 0.0, "cd": math.nan, "emd": math.nan}


def code_hash(decoder_tag: str, code: Tensor, resolution: int, shape_id: str) -> str:
    """Key of one reconstruction: the decoder, the exact code bytes, the mesh resolution and the target shape."""
    digest = hashlib.sha1(f"{decoder_tag}|{resolution}|{shape_id}|".encode())
    digest.update(code.detach().float().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()[:24]


def decode_mesh(decoder, code: Tensor, resolution: int) -> trimesh.Trimesh:
    """Mesh of the decoder's zero level set for one code [D] (coarse-to-fine marching cubes over [-1, 1]^3)."""
    with frozen(decoder):
        # Coarse pass at half of the resolution (at least 8 points per axis), as extraction allows.
        mesh, _ = extract_mesh(lambda p: decode_points(decoder, code, p, chunk=65536), resolution,
                               coarse_resolution=max(8, min(32, resolution // 2)))
    return mesh


class Reconstructor:
    """Meshes and scores codes for one decoder and one world, caching GT references and scores."""

    def __init__(self, decoder, decoder_tag: str, world: WorldIndex, resolution: int = 64,
                 cache_dir: str | Path | None = None, voxels: int = PIX3D_VOXELS, n_points: int = PIX3D_POINTS) -> None:
        self.decoder, self.decoder_tag, self.world = decoder, decoder_tag, world
        self.resolution, self.voxels, self.n_points = resolution, voxels, n_points
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        self._references: dict[str, ShapeReference] = {}
        self._scores: dict[str, dict] = {}

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
        key = code_hash(self.decoder_tag, code, self.resolution, shape_id)
        cached = self._load(key)
        if cached is not None and (not emd or "emd" in cached):
            return cached
        try:
            mesh = decode_mesh(self.decoder, code, self.resolution)
            inside = sdf_inside_fn(lambda p: decode_points(self.decoder, code, p, chunk=65536))
            result = pix3d_metrics(mesh, inside, self.reference(shape_id), emd=emd or (cached or {}).get("emd") is not None)
        except EmptySurfaceError:
            result = dict(EMPTY_SCORES)
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
