"""Pix3D's reconstruction metrics (Sun et al. 2018), each shape in its own normalised frame.

Protocol: every shape is normalised so its bounding box is centred at the origin with longest
side 1. IoU is taken on 32^3 voxels tiling that unit box [-0.5, 0.5]^3; a voxel is occupied when
its centre is inside the shape. Chamfer distance (CD) and Earth Mover's distance (EMD) compare
1024 points sampled uniformly by area on each normalised surface:

    CD  = mean_a min_b ||a - b|| + mean_b min_a ||a - b||     (plain, not squared, distances)
    EMD = min over one-to-one matchings phi of mean_a ||a - phi(a)||

How each side is voxelised (document, since it moves IoU): the prediction by its decoder's SDF
(inside where f < 0) or, for an analytic shape, its own inside test; the ground truth by a ray-
parity inside test of its watertight mesh. Both are queried at the voxel centres mapped back from
the unit box into the shape's frame, so neither needs a voxeliser.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import trimesh
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from ushape.metrics.reconstruction import iou_from_occupancy

InsideFn = Callable[[np.ndarray], np.ndarray]  # points [P, 3] -> bool [P]

PIX3D_VOXELS = 32
PIX3D_POINTS = 1024


@dataclass(frozen=True)
class BoxFrame:
    """Bounding-box normalisation x_unit = (x - centre) / scale (scale = the longest box side)."""

    centre: np.ndarray  # [3]
    scale: float

    def to_unit(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points, dtype=np.float64) - self.centre) / self.scale

    def from_unit(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, dtype=np.float64) * self.scale + self.centre


def box_frame(points: np.ndarray) -> BoxFrame:
    """The frame that centres the bounding box of points [P, 3] and scales its longest side to 1."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise ValueError(f"points must be a non-empty [P, 3] array, got shape {points.shape}")
    low, high = points.min(axis=0), points.max(axis=0)
    scale = float((high - low).max())
    if scale <= 0:
        raise ValueError("the shape is a single point (zero-size bounding box); it cannot be normalised")
    return BoxFrame(centre=(low + high) / 2, scale=scale)


def unit_voxel_centres(resolution: int = PIX3D_VOXELS) -> np.ndarray:
    """Centres [R^3, 3] of the R^3 voxels tiling the unit box [-0.5, 0.5]^3, x slowest."""
    if resolution < 1:
        raise ValueError(f"resolution must be >= 1 voxel per side, got {resolution}")
    axis = -0.5 + (np.arange(resolution) + 0.5) / resolution
    return np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)


def voxelise(inside_fn: InsideFn, frame: BoxFrame, resolution: int = PIX3D_VOXELS) -> np.ndarray:
    """Occupancy bool [R, R, R] of a shape in its normalised unit box (voxel centre inside the shape)."""
    inside = np.asarray(inside_fn(frame.from_unit(unit_voxel_centres(resolution))), dtype=bool)
    return inside.reshape((resolution,) * 3)


def voxel_iou(occupancy_a: np.ndarray, occupancy_b: np.ndarray) -> float:
    """IoU of two occupancy grids of the same resolution (each already in its own normalised frame)."""
    return iou_from_occupancy(occupancy_a, occupancy_b)


def sample_surface(mesh: trimesh.Trimesh, n_points: int = PIX3D_POINTS, seed: int = 0) -> np.ndarray:
    """n_points points [N, 3] uniformly by area on the mesh surface, repeatable through `seed`."""
    if len(mesh.faces) == 0:
        raise ValueError("the mesh has no faces; there is no surface to sample points from")
    points, _ = trimesh.sample.sample_surface(mesh, n_points, seed=seed)
    return np.asarray(points, dtype=np.float64)


def chamfer_pix3d(a: np.ndarray, b: np.ndarray) -> float:
    """Pix3D's Chamfer distance of point sets a [N, 3], b [M, 3]: mean NN distance each way, summed."""
    a, b = _points(a, "a"), _points(b, "b")
    a_to_b, _ = cKDTree(b).query(a)
    b_to_a, _ = cKDTree(a).query(b)
    return float(a_to_b.mean() + b_to_a.mean())


def earth_movers(a: np.ndarray, b: np.ndarray) -> float:
    """EMD of equal-size point sets a, b [N, 3]: mean distance of the optimal one-to-one matching."""
    a, b = _points(a, "a"), _points(b, "b")
    if len(a) != len(b):
        raise ValueError(f"EMD needs equally many points on both sides, got {len(a)} and {len(b)}")
    cost = cdist(a, b)
    rows, cols = linear_sum_assignment(cost)
    return float(cost[rows, cols].mean())


def _points(x: np.ndarray, name: str) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or len(x) == 0:
        raise ValueError(f"{name} must be a non-empty [N, 3] point array, got shape {x.shape}")
    return x


@dataclass(frozen=True)
class ShapeReference:
    """What a prediction is compared against: the ground truth's voxels and surface points, normalised."""

    occupancy: np.ndarray  # bool [R, R, R]
    points: np.ndarray  # [N, 3] in the unit box


def reference_from_mesh(
    mesh: trimesh.Trimesh, resolution: int = PIX3D_VOXELS, n_points: int = PIX3D_POINTS, seed: int = 0
) -> ShapeReference:
    """Normalise a watertight ground-truth mesh by its box; voxelise it by ray parity; sample its surface."""
    frame = box_frame(mesh.vertices)
    occupancy = voxelise(lambda p: mesh.contains(p), frame, resolution)
    return ShapeReference(occupancy, frame.to_unit(sample_surface(mesh, n_points, seed)))


def pix3d_metrics(
    mesh: trimesh.Trimesh,
    inside_fn: InsideFn,
    reference: ShapeReference,
    emd: bool = True,
    seed: int = 1,
) -> dict[str, float]:
    """IoU (32^3 voxels), CD and (if asked) EMD of a predicted mesh and its inside test against the reference.

    The prediction is normalised by the bounding box of `mesh`; `inside_fn` answers in the mesh's frame.
    """
    frame = box_frame(mesh.vertices)
    occupancy = voxelise(inside_fn, frame, reference.occupancy.shape[0])
    points = frame.to_unit(sample_surface(mesh, len(reference.points), seed))
    scores = {"iou": voxel_iou(occupancy, reference.occupancy), "cd": chamfer_pix3d(points, reference.points)}
    if emd:
        scores["emd"] = earth_movers(points, reference.points)
    return scores
