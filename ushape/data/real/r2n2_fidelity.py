"""How close the voxel-derived surface of `r2n2_voxels` is to a model's true mesh, and whether the frames agree.

For a model in both ShapeNetVox32 and ShapeNetCore.v2 (the shared chair): the v2 mesh, moved into
R2N2's frame (its bounding-box centre to the origin, v2's axes turned back to v1's; v2 meshes
already have a unit diagonal), against the voxel surface; Chamfer-L1 (mean of both directions'
mean point-to-surface distance, in R2N2's units: the model's bounding-box diagonal is 1) and
volume IoU on points drawn in the mesh's box. `frame_offset` shifts the voxel surface to show that
the centred frame is the one that fits.

    python -m ushape.data.real.r2n2_fidelity VOXELS.binvox MESH.obj     (prints a table; docs/r2n2.md)
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import igl
import numpy as np
import trimesh

from ushape.data.cameras import FRAME_FROM_V1
from ushape.data.real import r2n2_voxels
from ushape.data.real.mesh_sdf import MeshSdf, load_mesh


@dataclass(frozen=True)
class Fidelity:
    chamfer_l1: float  # R2N2 units (bounding-box diagonal 1)
    iou: float
    faces: int


def v2_mesh_in_r2n2_frame(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """A ShapeNetCore.v2 model_normalized mesh in R2N2's frame: box centre at the origin, v1's axes."""
    lo, hi = mesh.bounds
    # p_v2 = M p_v1 (ushape.data.cameras), so p_v1 = M^T p_v2, i.e. rows times M.
    vertices = (np.asarray(mesh.vertices) - (lo + hi) / 2.0) @ FRAME_FROM_V1["v2"]
    return trimesh.Trimesh(vertices, mesh.faces, process=False)


def surface_fidelity(
    surface: trimesh.Trimesh,
    truth: trimesh.Trimesh,
    truth_inside: np.ndarray,
    query: np.ndarray,
    n_surface: int = 20_000,
    seed: int = 0,
) -> Fidelity:
    """Chamfer-L1 and IoU of a closed surface against the true mesh; truth_inside [N] for query points [N,3]."""
    inside = r2n2_voxels.closed_mesh_sdf(surface, query) < 0
    iou = float((inside & truth_inside).sum() / max((inside | truth_inside).sum(), 1))
    ours, _ = trimesh.sample.sample_surface(surface, n_surface, seed=seed)
    theirs, _ = trimesh.sample.sample_surface(truth, n_surface, seed=seed)
    to_truth = np.sqrt(igl.point_mesh_squared_distance(ours, truth.vertices, np.asarray(truth.faces, np.int64))[0])
    to_ours = np.sqrt(igl.point_mesh_squared_distance(theirs, surface.vertices, np.asarray(surface.faces, np.int64))[0])
    return Fidelity(float((to_truth.mean() + to_ours.mean()) / 2.0), iou, len(surface.faces))


def query_points(truth: trimesh.Trimesh, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(points [n,3] uniform in the true mesh's box grown by 0.02, inside [n] by its winding number)."""
    lo, hi = truth.bounds
    points = np.random.default_rng(seed).uniform(lo - 0.02, hi + 0.02, size=(n, 3))
    return points, MeshSdf(truth).inside(points)


def sweep(voxel_file: str, mesh_file: str, n_query: int = 100_000) -> list[tuple[str, Fidelity]]:
    """Fidelity of the blocky voxels, a few (sigma, level) surfaces, and the chosen one shifted by a quarter voxel."""
    occupancy, side = r2n2_voxels.read_r2n2_voxels(voxel_file)
    truth = v2_mesh_in_r2n2_frame(load_mesh(mesh_file))
    query, inside = query_points(truth, n_query)
    rows = []
    for sigma, level in ((0.0, 0.5), (0.0, 0.7), (0.5, 0.5), (0.5, 0.6), (0.5, 0.7), (0.75, 0.6), (1.0, 0.5)):
        surface = r2n2_voxels.voxel_surface(occupancy, side, sigma, level)
        rows.append((f"sigma {sigma} level {level}", surface_fidelity(surface, truth, inside, query)))
    chosen = r2n2_voxels.voxel_surface(occupancy, side)
    quarter = side / occupancy.shape[0] / 4.0
    for axis in range(3):
        for sign in (1, -1):
            shifted = chosen.copy()
            shifted.vertices = shifted.vertices + sign * quarter * np.eye(3)[axis]
            rows.append(
                (
                    f"chosen, shifted {sign:+d}/4 voxel along {'xyz'[axis]}",
                    surface_fidelity(shifted, truth, inside, query),
                )
            )
    return rows


if __name__ == "__main__":
    for name, fid in sweep(sys.argv[1], sys.argv[2]):
        print(f"{name:40s} chamfer-L1 {fid.chamfer_l1:.4f}  IoU {fid.iou:.3f}  faces {fid.faces}")
