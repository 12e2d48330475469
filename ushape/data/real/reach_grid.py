"""Which space around a mesh can be reached from outside: a surface voxelisation and an exterior flood fill.

The official voxels of ShapeNet and Pix3D follow one convention: a point is inside when it cannot
be reached from outside without crossing the surface. A sealed hollow between closed parts is
inside, an open drawer or a seat without its back is outside, whatever the faces' winding or
duplication. `ReachGrid` computes that convention on a grid:

1. Mark every voxel holding a point of a dense lattice on the triangles (any point of a triangle
   lies within 0.45 voxel of a lattice point, so no 6-connected path of unmarked voxels crosses
   the surface: where a surface crosses the segment between two neighbouring voxel centres it
   holds a disc of radius half a voxel inside the pair, and a lattice point in that disc).
2. Flood-fill the unmarked voxels from the grid's boundary (fill-voids: 0.2 s at 256^3 against
   0.3-0.5 s for connected-components-3d or scipy.ndimage.label, in bool memory); what the
   fill does not reach is inside.
3. A voxel whose 3x3x3 block holds no mark is `free`: no triangle touches it (every triangle point
   has a lattice point within half a voxel), so each point in it has the voxel's label.

Gaps narrower than about one voxel are sealed: the grid resolution is the convention's
resolution (the official voxels are 128^3; 256^3 here by default).
"""

from __future__ import annotations

from dataclasses import dataclass

import fill_voids
import numpy as np

LATTICE_SPACING = 0.4  # lattice step on the triangles, in voxels: every surface point within 0.45 voxel of one
PAD = 2  # empty voxels around the mesh's bounding box, so the fill enters from every side
LATTICE_CHUNK = 4_000_000  # lattice points generated at a time (~100 MB of float64 coordinates)


def surface_lattice(corners: np.ndarray, spacing: float):
    """Yield chunks of points [M,3] on triangles [F,3,3]: every triangle point within 1.12 * spacing of one.

    Each triangle is cut into slices parallel to its longest edge, at most `spacing` apart, and each
    slice is sampled at most `spacing` apart, ends included: about area / spacing^2 points however
    thin the triangle.
    """
    edges = np.roll(corners, -1, axis=1) - corners  # edge k runs from corner k to corner k+1
    lengths = np.linalg.norm(edges, axis=2)
    longest = np.argmax(lengths, axis=1)
    rows = np.arange(len(corners))
    a = corners[rows, longest]
    b = corners[rows, (longest + 1) % 3]
    c = corners[rows, (longest + 2) % 3]
    base = np.maximum(lengths[rows, longest], 1e-300)
    height = np.linalg.norm(np.cross(b - a, c - a), axis=1) / base
    n_slices = np.ceil(height / spacing).astype(np.int64) + 1  # slices at v = j / (n - 1), j < n (v = 1 is c)
    face = np.repeat(rows, n_slices)
    first = np.cumsum(n_slices) - n_slices
    j = np.arange(len(face)) - np.repeat(first, n_slices)
    v = j / np.maximum(np.repeat(n_slices, n_slices) - 1, 1)
    n_along = np.ceil((1 - v) * base[face] / spacing).astype(np.int64) + 1
    left = a[face] + v[:, None] * (c[face] - a[face])  # each slice's ends, then its step from left to right
    step = (b[face] + v[:, None] * (c[face] - b[face]) - left) / np.maximum(n_along - 1, 1)[:, None]
    ends = np.cumsum(n_along)
    start = 0
    while start < len(face):
        stop = int(np.searchsorted(ends, ends[start] - n_along[start] + LATTICE_CHUNK, side="right"))
        stop = max(stop, start + 1)
        counts = n_along[start:stop]
        owner = np.repeat(np.arange(start, stop), counts)
        k = np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts)
        yield left[owner] + k[:, None] * step[owner]
        start = stop


def box_dilation(grid: np.ndarray) -> np.ndarray:
    """Bool grid [X,Y,Z]: some voxel of the 3x3x3 block around is set (as three 1-D passes; 10x scipy's 3-D one)."""
    out = grid.copy()
    for axis in range(3):
        before = out.copy()
        lead = [slice(None)] * 3
        lag = [slice(None)] * 3
        lead[axis], lag[axis] = slice(1, None), slice(None, -1)
        out[tuple(lead)] |= before[tuple(lag)]
        out[tuple(lag)] |= before[tuple(lead)]
    return out


@dataclass(frozen=True)
class ReachGrid:
    """Exterior and free voxels of a mesh at one resolution; voxel (i,j,k) spans origin + [i,i+1) * pitch."""

    resolution: int  # voxels along the longest side of the mesh's bounding box, pads included
    origin: np.ndarray  # [3]
    pitch: float
    exterior: np.ndarray  # bool [X,Y,Z]: unmarked and reached by the fill from the boundary
    free: np.ndarray  # bool [X,Y,Z]: no mark in its 3x3x3 block, so no triangle touches it

    marked: np.ndarray  # bool [X,Y,Z]: holds a lattice point of the surface

    @classmethod
    def build(cls, vertices: np.ndarray, faces: np.ndarray, resolution: int = 256) -> "ReachGrid":
        """Grid of `resolution` voxels along the longest side of the mesh's bounding box (fewer along the others)."""
        if resolution < 2 * PAD + 2:
            raise ValueError(f"resolution must be at least {2 * PAD + 2} voxels, got {resolution}")
        corners = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]
        lo, hi = corners.reshape(-1, 3).min(axis=0), corners.reshape(-1, 3).max(axis=0)
        pitch = max(float((hi - lo).max()), 1e-12) / (resolution - 2 * PAD)
        origin = lo - PAD * pitch
        shape = np.ceil((hi - origin) / pitch).astype(np.int64) + PAD
        marked = np.zeros(tuple(shape), bool)
        for points in surface_lattice(corners, LATTICE_SPACING * pitch):
            index = np.floor((points - origin) / pitch).astype(np.int64)
            marked[tuple(np.clip(index, 0, shape - 1).T)] = True
        return cls.of_marks(marked, origin, pitch, resolution)

    @classmethod
    def of_marks(cls, marked: np.ndarray, origin: np.ndarray, pitch: float, resolution: int) -> "ReachGrid":
        """The grid of surface marks [X,Y,Z] whose boundary voxels are unmarked: the fill and the free voxels."""
        exterior = ~fill_voids.fill(marked, in_place=False)
        free = ~box_dilation(marked)
        return cls(resolution=resolution, origin=origin, pitch=pitch, exterior=exterior, free=free, marked=marked)

    def coarsened(self, factor: int) -> "ReachGrid":
        """The grid with voxels `factor` times as large: marked where any of its fine voxels is (the same lattice)."""
        if factor == 1:
            return self
        shape = -(-np.array(self.marked.shape) // factor)
        fine = np.zeros(tuple(shape * factor), bool)
        fine[tuple(slice(0, n) for n in self.marked.shape)] = self.marked
        coarse = fine.reshape(shape[0], factor, shape[1], factor, shape[2], factor).any(axis=(1, 3, 5))
        pitch = self.pitch * factor
        return ReachGrid.of_marks(np.pad(coarse, 1), self.origin - pitch, pitch, -(-self.resolution // factor))

    def index(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(voxel index [N,3] clipped to the grid, in_grid [N]) of points [N,3]."""
        index = np.floor((points - self.origin) / self.pitch).astype(np.int64)
        shape = np.array(self.exterior.shape)
        in_grid = np.all((index >= 0) & (index < shape), axis=1)
        return np.clip(index, 0, shape - 1), in_grid

    def lookup(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(free [N], exterior [N]) of the voxels holding points [N,3]; beyond the grid is free exterior."""
        index, in_grid = self.index(points)
        cell = tuple(index.T)
        return ~in_grid | self.free[cell], ~in_grid | self.exterior[cell]
