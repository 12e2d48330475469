"""Inside/outside signs checked against official voxelisations (ShapeNet's solid binvox, Pix3D's voxel.mat).

Voxels are a coarse reference: a face lying on a voxel boundary and a thin part thickened to a
whole voxel both make the voxel's answer differ from the mesh's near the surface. So a point is
compared only when its voxel and all 26 neighbours agree, i.e. when it lies at least one voxel
from the voxel surface; points outside the grid count as outside.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage
from trimesh.exchange.binvox import parse_binvox, voxel_from_binvox


def read_solid_binvox(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(occupancy bool [D,D,D] indexed x,y,z, [4,4] map from voxel-centre indices to model coordinates)."""
    with open(path, "rb") as fh:
        data = parse_binvox(fh)
    occupancy = voxel_from_binvox(data.rle_data, data.shape, axis_order="xzy").encoding.dense
    step = data.scale / data.shape[0]
    # binvox_rw convention: voxel i covers translate + [i, i+1) * scale / dim.
    index_to_model = np.diag([step, step, step, 1.0])
    index_to_model[:3, 3] = np.asarray(data.translate) + 0.5 * step
    return occupancy, index_to_model


def tolerant_truth(
    occupancy: np.ndarray, index_to_model: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(checked [N], inside [N]) for model-frame points [N,3]: checked where the 3x3x3 voxels around agree."""
    padded = np.pad(occupancy.astype(bool), 1)  # beyond the grid is empty
    block = np.ones((3, 3, 3), bool)
    solid = ndimage.binary_erosion(padded, block, border_value=0)
    empty = ndimage.binary_erosion(~padded, block, border_value=1)
    to_index = np.linalg.inv(index_to_model)
    index = np.rint(points @ to_index[:3, :3].T + to_index[:3, 3]).astype(np.int64) + 1
    in_padded = np.all((index >= 0) & (index < np.array(padded.shape)), axis=1)
    clipped = np.clip(index, 0, np.array(padded.shape) - 1)
    inside = in_padded & solid[tuple(clipped.T)]
    checked = ~in_padded | inside | empty[tuple(clipped.T)]
    return checked, inside


def has_interior(occupancy: np.ndarray) -> bool:
    """Whether any occupied voxel has all 26 neighbours occupied (False: a hollow, surface-only voxelisation)."""
    return bool(ndimage.binary_erosion(occupancy.astype(bool), np.ones((3, 3, 3), bool)).any())
