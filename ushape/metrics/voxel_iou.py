"""IoU against 3D-R2N2's 32^3 voxels, as 3D-R2N2, Pix2Vox and LRGT score ShapeNet.

Those methods predict the 32^3 occupancy grid itself; a decoder predicts an SDF in its own unit-sphere
frame. To score it on R2N2's grid, the grid's voxel centres are taken into the decoder's frame
(p = (p_r2n2 - centre) * scale, the world's normalisation of that shape, shapes/<id>.json) and a voxel
counts as occupied where the SDF at its centre is below `level` voxel widths. R2N2's voxelisation is
conservative (every voxel the surface touches is full), so the right level is above 0: a voxel whose
centre lies up to half a voxel outside a thin leg is full in R2N2's grid. The level is chosen once, on
the world's own voxel surfaces (the closed surface fitted to each shape's voxels, the training target):
the level at which that surface reproduces its voxels best, which is also the bound any decoder
trained on it can reach (`bound`). Predictions are then scored at that same level.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import torch

from ushape.data.real.r2n2_voxels import voxel_centres
from ushape.metrics.reconstruction import iou_from_occupancy

# points [P, 3] in the decoder's frame -> SDF [P] in that frame
SDFFn = Callable[[np.ndarray], np.ndarray]
# Levels tried for the bound, in voxel widths (0: the voxel centre inside; 0.5: within half a voxel).
LEVELS = tuple(np.round(np.arange(-0.2, 0.91, 0.1), 2))
# The level the r2n2 worlds are scored at: where their own voxel surfaces match R2N2's voxels best on val
# (the bound, chairs and tables alike; docs/pretrained.md).
PROTOCOL_LEVEL = 0.4


def numpy_sdf(sdf: Callable[[torch.Tensor], torch.Tensor]) -> SDFFn:
    """A torch SDF (points [P, 3] -> [P], e.g. decoder.query.code_sdf_fn) as the numpy function the IoUs here
    take: float32 points, no autograd."""

    def values(points: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return sdf(torch.as_tensor(np.asarray(points), dtype=torch.float32)).numpy()

    return values


def voxel_centres_in_frame(side: float, n: int, centre: Sequence[float], scale: float) -> np.ndarray:
    """Centres [n^3, 3] of R2N2's grid (`r2n2_voxels.voxel_centres`, C order), in the decoder's frame
    p = (p_r2n2 - centre) * scale."""
    grid = voxel_centres((n, n, n), side).reshape(-1, 3)
    return (grid - np.asarray(centre, dtype=np.float64)) * scale


def occupancy_at_level(
    sdf_fn: SDFFn, n: int, side: float, centre: Sequence[float], scale: float, level: float
) -> np.ndarray:
    """Bool [n, n, n]: the voxels whose centre's SDF is below `level` voxel widths (in the decoder's frame)."""
    sdf = np.asarray(sdf_fn(voxel_centres_in_frame(side, n, centre, scale)), dtype=np.float64)
    width = side / n * scale  # a voxel's width in the decoder's frame
    return (sdf < level * width).reshape(n, n, n)


def voxel_iou(
    sdf_fn: SDFFn, voxels: np.ndarray, side: float, centre: Sequence[float], scale: float, level: float
) -> float:
    """IoU of the SDF's occupancy at `level` with R2N2's voxels (bool [n, n, n], indexed as the grid above)."""
    n = voxels.shape[0]
    return iou_from_occupancy(occupancy_at_level(sdf_fn, n, side, centre, scale, level), voxels)


def ious_at_levels(
    sdf_fn: SDFFn, voxels: np.ndarray, side: float, centre: Sequence[float], scale: float, levels=LEVELS
) -> np.ndarray:
    """IoU [L] with the voxels at each level (one SDF evaluation for all of them)."""
    n = voxels.shape[0]
    sdf = np.asarray(sdf_fn(voxel_centres_in_frame(side, n, centre, scale)), dtype=np.float64).reshape(n, n, n)
    width = side / n * scale
    return np.array([iou_from_occupancy(sdf < level * width, voxels) for level in levels])
