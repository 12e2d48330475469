"""A two-part analytic shape implementing the ushape.shapes Shape protocol, for data-pipeline tests."""

from __future__ import annotations

import numpy as np
import trimesh
from skimage.measure import marching_cubes


def _box_sdf(points: np.ndarray, centre: np.ndarray, half: np.ndarray) -> np.ndarray:
    q = np.abs(points - centre) - half
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)


class ToyShape:
    """A ball resting on a block; sizes drawn from the seed."""

    part_names = ("ball", "block")

    def __init__(self, category: str, seed: int) -> None:
        rng = np.random.default_rng(seed)
        self.category = category
        self.shape_id = f"{category}-toy-{seed:010d}"
        self.radius = float(rng.uniform(0.25, 0.35))
        self.centre = np.array([0.0, 0.3, 0.0])
        self.half = np.array([rng.uniform(0.2, 0.3), 0.25, rng.uniform(0.15, 0.25)])
        self.block_centre = np.array([0.0, -0.2, 0.0])
        self.style = {"radius": self.radius, "block_half": self.half.tolist(), "seed": np.int64(seed)}

    def _part_sdfs(self, points: np.ndarray) -> np.ndarray:
        ball = np.linalg.norm(points - self.centre, axis=1) - self.radius
        return np.stack([ball, _box_sdf(points, self.block_centre, self.half)], axis=1)

    def sdf(self, points: np.ndarray) -> np.ndarray:
        return self._part_sdfs(np.asarray(points, float)).min(axis=1)

    def part_index(self, points: np.ndarray) -> np.ndarray:
        return self._part_sdfs(np.asarray(points, float)).argmin(axis=1)

    def part_colours(self) -> np.ndarray:
        return np.array([[0.8, 0.35, 0.2], [0.25, 0.45, 0.8]])

    def mesh(self, resolution: int = 256) -> trimesh.Trimesh:
        axis = np.linspace(-1.0, 1.0, resolution)
        grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
        volume = self.sdf(grid).reshape(resolution, resolution, resolution)
        spacing = (axis[1] - axis[0],) * 3
        verts, faces, _, _ = marching_cubes(volume, level=0.0, spacing=spacing)
        return trimesh.Trimesh(verts - 1.0, faces, process=True)


def toy_shape_factory(category: str, seed: int) -> ToyShape:
    return ToyShape(category, seed)
