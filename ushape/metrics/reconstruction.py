"""Reconstruction metrics in the normalised object frame: Chamfer distance and volumetric IoU."""

from __future__ import annotations

import warnings
from typing import Callable

import numpy as np
import torch
import trimesh
from scipy.spatial import cKDTree

from ushape.mesh.extraction import DEFAULT_CHUNK, evaluate_sdf

# points [P, 3] float -> bool [P], True inside the shape.
InsideFn = Callable[[np.ndarray], np.ndarray]


def chamfer_deepsdf(
    mesh_gt: trimesh.Trimesh, mesh_pred: trimesh.Trimesh, n_points: int = 30000, seed: int = 0
) -> float:
    """DeepSDF's Chamfer distance: mean squared NN distance gt->pred plus pred->gt, on surface samples.

    As in DeepSDF's evaluation, `n_points` points are sampled uniformly (by area) on each surface;
    the distances are *squared* and not halved, so two concentric spheres of radii r1, r2 score
    about 2 (r1 - r2)^2.
    """
    for name, mesh in (("ground-truth", mesh_gt), ("predicted", mesh_pred)):
        if len(mesh.faces) == 0:
            raise ValueError(f"the {name} mesh has no faces; Chamfer distance needs a surface to sample")
    rng = np.random.default_rng(seed)
    gt_points, _ = trimesh.sample.sample_surface(mesh_gt, n_points, seed=int(rng.integers(2**31)))
    pred_points, _ = trimesh.sample.sample_surface(mesh_pred, n_points, seed=int(rng.integers(2**31)))
    gt_to_pred, _ = cKDTree(pred_points).query(gt_points)
    pred_to_gt, _ = cKDTree(gt_points).query(pred_points)
    return float(np.mean(gt_to_pred**2) + np.mean(pred_to_gt**2))


class EmptyOccupancyError(ValueError):
    """Neither shape occupies any voxel, so their IoU is undefined (a caller may read it as "no IoU", e.g. NaN)."""


def iou_from_occupancy(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean occupancy arrays of the same shape."""
    a, b = np.asarray(a, dtype=bool), np.asarray(b, dtype=bool)
    if a.shape != b.shape:
        raise ValueError(f"occupancy shapes differ: {a.shape} vs {b.shape}")
    union = np.logical_or(a, b).sum()
    if union == 0:
        raise EmptyOccupancyError("both occupancies are empty, so IoU is undefined")
    return float(np.logical_and(a, b).sum() / union)


def voxel_centres(resolution: int) -> np.ndarray:
    """Centres of the resolution^3 voxels tiling [-1, 1]^3, C order (x slowest). -> [R^3, 3]"""
    axis = -1.0 + (np.arange(resolution) + 0.5) * (2.0 / resolution)
    return np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)


def occupancy_grid(inside_fn: InsideFn, resolution: int = 64) -> np.ndarray:
    """Which voxel centres of [-1, 1]^3 are inside the shape. -> bool [R, R, R]"""
    inside = np.asarray(inside_fn(voxel_centres(resolution)), dtype=bool)
    return inside.reshape(resolution, resolution, resolution)


def volumetric_iou(inside_a: InsideFn, inside_b: InsideFn, resolution: int = 64) -> float:
    """IoU of two shapes, voxelised at the voxel centres of a resolution^3 grid over [-1, 1]^3."""
    return iou_from_occupancy(occupancy_grid(inside_a, resolution), occupancy_grid(inside_b, resolution))


def mesh_inside_fn(mesh: trimesh.Trimesh) -> InsideFn:
    """Inside test of a watertight mesh (ray parity; embree-accelerated when embreex is installed)."""
    if not mesh.is_watertight:
        # Ray parity still holds away from the holes, so score the shape rather than stop a run.
        warnings.warn(
            f"mesh with {len(mesh.faces)} faces is not watertight: its inside test (and IoU) "
            "may be wrong near the holes",
            stacklevel=2,
        )
    return lambda points: mesh.contains(np.asarray(points, dtype=np.float64))


def sdf_inside_fn(sdf_fn: Callable[[torch.Tensor], torch.Tensor], chunk: int = DEFAULT_CHUNK) -> InsideFn:
    """Inside test of an SDF callable (points [P, 3] tensor -> sdf [P]): inside where sdf < 0."""

    def inside(points: np.ndarray) -> np.ndarray:
        sdf = evaluate_sdf(sdf_fn, torch.as_tensor(np.asarray(points), dtype=torch.float32), chunk)
        return (sdf < 0).numpy()

    return inside
