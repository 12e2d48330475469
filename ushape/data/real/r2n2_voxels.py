"""3D-R2N2's ShapeNetVox32 voxels: reading them in R2N2's frame, and the watertight surface they imply.

    <voxels_root>/<synset>/<model_id>/model.binvox        32^3, binvox run-length encoding

Frame (checked on the shared chair, whose ShapeNetCore.v2 mesh is in ../shared/data/real_sample;
docs/r2n2.md): the grid is a cube of side `scale` (the header's value: the largest extent of the
model scaled to a unit bounding-box diagonal) *centred on the model's bounding-box centre*, in
ShapeNetCore v1's axes (x front, y up), with the data in binvox's x-z-y order. The header's
`translate` is the box's lower corner, not the grid's origin, so reading the grid with it (as
binvox readers do) puts it up to a quarter of its side off the model; centred, it overlaps the true
mesh best (any quarter-voxel shift lowers the IoU). This is the frame R2N2 rendered ShapeNetRendering
in, so a voxel surface in it is placed by R2N2's cameras as the real model was.

Surface: the occupancy, padded empty, blurred by a Gaussian of SMOOTHING_SIGMA voxels, then marching
cubes at ISO_LEVEL. R2N2's voxelisation is conservative (every voxel the surface touches is full),
so the boundary layer is about half a voxel too thick; a level above 1/2 puts the surface back
inside that layer. The result is closed by construction (the padding), so its inside is simply the
enclosed volume: signed distance is exact distance to it with the sign of its pseudo-normal.
"""

from __future__ import annotations

from pathlib import Path

import igl
import numpy as np
import trimesh
from scipy import ndimage
from skimage.measure import marching_cubes
from trimesh.exchange.binvox import parse_binvox, voxel_from_binvox

VOXEL_FILE = "model.binvox"
BINVOX_MAGIC = b"#binvox"
SMOOTHING_SIGMA = 0.5  # voxels; chosen on the shared chair (docs/r2n2.md)
ISO_LEVEL = 0.7
PADDING = 2
EXPECTED_LAYOUT = "<voxels_root>/<synset>/<model_id>/model.binvox (ShapeNetVox32.tgz from 3D-R2N2, unpacked)"


class VoxelError(ValueError):
    """A model whose voxels cannot become a surface (missing, unreadable, empty)."""


def error_text(err: BaseException) -> str:
    """`Type: message`, with a %-style message whose arguments came apart (as trimesh raises some) filled in."""
    if len(err.args) >= 2 and isinstance(err.args[0], str) and "%" in err.args[0]:
        template, *rest = err.args
        values = rest[0] if len(rest) == 1 and isinstance(rest[0], tuple) else tuple(rest)
        try:
            return f"{type(err).__name__}: {template % values}"
        except (TypeError, ValueError):
            pass
    return f"{type(err).__name__}: {err}"


def voxel_path(root: str | Path, synset: str, model_id: str) -> Path:
    return Path(root).expanduser() / synset / model_id / VOXEL_FILE


def read_r2n2_voxels(path: str | Path) -> tuple[np.ndarray, float]:
    """(occupancy bool [D,D,D] indexed by v1's x, y, z, cube side in R2N2's unit-diagonal frame)."""
    path = Path(path)
    if not path.is_file():
        raise VoxelError(f"voxel file {path} is missing. Expected {EXPECTED_LAYOUT}")
    with open(path, "rb") as fh:
        if not fh.read(len(BINVOX_MAGIC)) == BINVOX_MAGIC:
            raise VoxelError(f"{path} is not a binvox file (it does not start with {BINVOX_MAGIC.decode()})")
        fh.seek(0)
        try:
            data = parse_binvox(fh)
        except Exception as err:  # noqa: BLE001  (trimesh's header parser raises whatever the bytes make it)
            raise VoxelError(f"cannot read {path}'s header: {error_text(err)}") from err
    dims = tuple(int(d) for d in data.shape)
    runs = np.asarray(data.rle_data[1::2], dtype=np.int64)
    if len(data.rle_data) % 2 or runs.sum() != np.prod(dims):
        raise VoxelError(
            f"{path} is truncated or damaged: its run-length data covers {int(runs.sum())} of the header's "
            f"{'x'.join(map(str, dims))} = {int(np.prod(dims))} voxels"
        )
    try:
        occupancy = np.asarray(voxel_from_binvox(data.rle_data, dims, axis_order="xzy").encoding.dense, bool)
    except Exception as err:  # noqa: BLE001  (the RLE decoder)
        raise VoxelError(f"cannot decode {path}'s voxels: {error_text(err)}") from err
    side = float(data.scale)
    if occupancy.ndim != 3 or len(set(occupancy.shape)) != 1:
        raise VoxelError(f"{path}: expected a cubic grid, got {occupancy.shape}")
    if not np.isfinite(side) or side <= 0:
        raise VoxelError(f"{path}: the header's scale {side} is not a positive size")
    if not occupancy.any():
        raise VoxelError(f"{path}: the voxel grid is empty (no occupied voxel)")
    return occupancy, side


def voxel_centres(occupancy_shape: tuple[int, int, int], side: float) -> np.ndarray:
    """Centres [D,D,D,3] of a centred cubic grid of `side` in R2N2's frame."""
    n = occupancy_shape[0]
    axis = (np.arange(n) + 0.5) * (side / n) - side / 2.0
    return np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1)


def voxel_surface(
    occupancy: np.ndarray, side: float, sigma: float = SMOOTHING_SIGMA, level: float = ISO_LEVEL
) -> trimesh.Trimesh:
    """Closed surface of occupancy bool [D,D,D] in R2N2's frame (v1 axes, cube of `side` about the origin)."""
    grid = np.pad(occupancy.astype(np.float32), PADDING)
    if sigma > 0:
        grid = ndimage.gaussian_filter(grid, sigma)
    if grid.max() <= level:
        raise VoxelError(f"no voxel survives smoothing at level {level}: the occupied voxels are too sparse")
    vertices, faces, _, _ = marching_cubes(grid, level)
    step = side / occupancy.shape[0]
    vertices = (vertices - PADDING + 0.5) * step - side / 2.0
    # marching_cubes orders faces for an increasing field; the occupancy grows inward, so flip to face out.
    mesh = trimesh.Trimesh(vertices, faces[:, ::-1], process=False)
    if len(mesh.faces) == 0 or mesh.area <= 0:
        raise VoxelError("the voxel surface is empty")
    return mesh


def closed_mesh_sdf(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Signed distance [N] of points [N,3] to a closed mesh: exact distance, pseudo-normal sign (< 0 inside)."""
    distance, _, _, _ = igl.signed_distance(
        np.ascontiguousarray(points, np.float64),
        np.ascontiguousarray(mesh.vertices, np.float64),
        np.ascontiguousarray(mesh.faces, np.int64),
        sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL,
    )
    return np.asarray(distance, np.float64)
