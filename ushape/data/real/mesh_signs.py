"""Inside or outside a real CAD mesh, by the convention of the official voxels: inside when unreachable from outside.

Real meshes are unions of closed parts and open sheets, with faces stored twice, wound every
which way and meeting at non-manifold edges. None of that matters to reachability, which asks
only whether a path from outside reaches the point without crossing a face:

- a sealed hollow between closed parts (a tabletop built as a box of six closed plates) is
  inside, although its winding number is 0;
- an open drawer, a deep cubby and a seat whose back was never modelled are outside, however
  few straight rays leave them, which matches the hollow voxels such open models get.

1. `ReachGrid` at `resolution` (256 voxels along the longest side): surface voxels, an exterior
   flood fill, and the free voxels no triangle touches.
2. A sample at least one voxel diagonal from the mesh (exact distance) has its whole voxel in
   its ball of empty space: the voxel's label is its sign.
3. A nearer sample (about a quarter of a chair's samples) sees out along rays: first the
   direction away from its closest surface point, then, where that one is blocked or stays among
   surface voxels for `MAX_STEPS` voxels, `n_rays` spread directions. A ray that reaches a free
   voxel with no face on the way gives that voxel's label; any exterior one makes the sample
   outside. A sample no ray gets out from (inside a part thinner than a few voxels, or in a gap
   the grid seals) is inside, as the official voxels have it.

The sign confidence (`SignTally`) is the share of samples whose sign does not depend on the
method or the resolution: one minus the shares that flip between this grid and one at
`check_resolution`, and between reachability and the winding number of the outward-oriented
surface (`ushape.data.real.mesh_orientation`, |w| > 1/2), on samples far from the surface.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import trimesh
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh
from scipy.spatial.transform import Rotation

from ushape.data.real.mesh_orientation import OrientedSurface, clean_triangles, orient_surface, winding_number
from ushape.data.real.reach_grid import ReachGrid

RESOLUTION, CHECK_RESOLUTION = (
    256,
    128,
)  # voxels along the longest side: the signs' grid, and the one they are checked on
MAX_STEPS = 8  # a near sample's ray looks this many voxels far for a free voxel
N_RAYS = 16  # spread directions for near samples whose away ray is blocked
WINDING_CHECKS = 2000  # far samples per call checked against the winding number
RAY_CHUNK = 8192  # near samples per batch: N_RAYS x MAX_STEPS lookups each stay ~30 MB
EMBREE_SCALE = 100.0  # rays are cast in a frame where the mesh spans about this much (as trimesh does)


def sphere_directions(n: int) -> np.ndarray:
    """n near-uniform unit vectors [n,3] on the sphere (Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    polar = np.arccos(1.0 - 2.0 * i / n)
    azimuth = np.pi * (1.0 + 5.0**0.5) * i
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1)


def escape_fraction(mesh: trimesh.Trimesh, points: np.ndarray, n_rays: int, rng: np.random.Generator) -> np.ndarray:
    """Fraction [N] of n_rays rays from each point [N,3] that hit no triangle (the straight-line view out)."""
    if n_rays < 1:
        raise ValueError(f"n_rays must be at least 1, got {n_rays}")
    base = sphere_directions(n_rays)
    out = np.empty(len(points))
    for start in range(0, len(points), RAY_CHUNK):
        chunk = points[start : start + RAY_CHUNK]
        rotations = Rotation.random(len(chunk), random_state=rng).as_matrix()
        directions = np.einsum("pij,rj->pri", rotations, base).reshape(-1, 3)
        hit = mesh.ray.intersects_any(np.repeat(chunk, n_rays, axis=0), directions).reshape(len(chunk), n_rays)
        out[start : start + len(chunk)] = 1.0 - hit.mean(axis=1)
    return out


class SegmentTest:
    """Whether straight segments cross a mesh (Embree occlusion queries with a length limit)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self._origin = vertices.min(axis=0)
        self._scale = EMBREE_SCALE / max(float(np.ptp(vertices, axis=0).max()), 1e-12)
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(
            scene=self._scene,
            vertices=((vertices - self._origin) * self._scale).astype(np.float32),
            indices=faces.astype(np.int32),
        )

    def blocked(self, starts: np.ndarray, directions: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        """Bool [N]: a face lies on the segment start [N,3] + t * unit direction [N,3], 0 <= t <= length [N]."""
        if len(starts) == 0:
            return np.zeros(0, bool)
        hit = self._scene.run(
            ((starts - self._origin) * self._scale).astype(np.float32),
            directions.astype(np.float32),
            dists=(lengths * self._scale).astype(np.float32),
            query="OCCLUDED",
        )
        return np.asarray(hit) != -1


def look_out(
    grid: ReachGrid, segments: SegmentTest, points: np.ndarray, directions: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(reached [N,R], exterior [N,R]) for rays from points [N,3] along unit directions [N,R,3].

    A ray reaches the first free voxel within MAX_STEPS voxels along it when no face lies on the way;
    `exterior` is that voxel's label.
    """
    n, r = directions.shape[:2]
    steps = grid.pitch * np.arange(1, MAX_STEPS + 1)
    probes = points[:, None, None, :] + directions[:, :, None, :] * steps[:, None]  # [N,R,S,3]
    free, exterior = (a.reshape(n, r, MAX_STEPS) for a in grid.lookup(probes.reshape(-1, 3)))
    found = free.any(axis=2)
    first = np.argmax(free, axis=2)
    reached = found.copy()
    rays = np.flatnonzero(found.reshape(-1))
    blocked = segments.blocked(
        np.repeat(points, r, axis=0)[rays], directions.reshape(-1, 3)[rays], steps[first.reshape(-1)[rays]]
    )
    reached.reshape(-1)[rays[blocked]] = False
    exterior = np.take_along_axis(exterior, first[..., None], axis=2)[..., 0] & reached
    return reached, exterior


@dataclass
class SignTally:
    """Running counts over every point classified: how many needed rays, and how often the sign depends on method."""

    points: int = 0
    inside: int = 0
    near: int = 0  # nearer than a voxel diagonal to the mesh: decided by rays
    enclosed: int = 0  # near, and no ray got out: called inside (a thin part, or a gap the grid seals)
    resolution_checked: int = 0
    resolution_flips: int = 0  # far at both resolutions, with another sign at CHECK_RESOLUTION
    winding_checked: int = 0
    winding_flips: int = 0  # far samples whose winding number (|w| > 1/2) gives the other sign

    def share(self, count: float) -> float:
        return count / self.points if self.points else 0.0

    @property
    def resolution_agreement(self) -> float:
        return 1.0 - self.resolution_flips / self.resolution_checked if self.resolution_checked else 1.0

    @property
    def winding_agreement(self) -> float:
        return 1.0 - self.winding_flips / self.winding_checked if self.winding_checked else 1.0

    @property
    def confidence(self) -> float:
        """At least this share of far samples keeps its sign under either other method (union bound)."""
        return max(0.0, self.resolution_agreement + self.winding_agreement - 1.0)


class MeshSigns:
    """Inside test [N] for points [N,3] of a real mesh: unreachable from outside at `resolution` voxels."""

    def __init__(
        self,
        mesh: trimesh.Trimesh,
        resolution: int = RESOLUTION,
        check_resolution: int = CHECK_RESOLUTION,
        n_rays: int = N_RAYS,
        seed: int = 0,
    ) -> None:
        if n_rays < 1:
            raise ValueError(f"n_rays must be at least 1, got {n_rays}")
        self.n_rays = int(n_rays)
        self._rng = np.random.default_rng(seed)
        self.vertices, self.faces = clean_triangles(mesh.vertices, mesh.faces)
        if len(self.faces) == 0:
            raise ValueError("the mesh has no non-degenerate faces")
        self.grid = ReachGrid.build(self.vertices, self.faces, resolution)
        if resolution % check_resolution == 0:  # pooling the fine marks spares a second lattice
            self.check_grid = self.grid.coarsened(resolution // check_resolution)
        else:
            self.check_grid = ReachGrid.build(self.vertices, self.faces, check_resolution)
        self._segments = SegmentTest(self.vertices, self.faces)
        self.tally = SignTally()

    @cached_property
    def surface(self) -> OrientedSurface:
        """The outward-oriented faces the winding-number check uses (built on the first check)."""
        return orient_surface(self.vertices, self.faces, self._rng)

    def inside(self, points: np.ndarray, distance: np.ndarray, closest: np.ndarray) -> np.ndarray:
        """Bool [N] for points [N,3], given each one's distance [N] to the mesh and closest mesh point [N,3]."""
        points = np.asarray(points, np.float64)
        far = distance >= np.sqrt(3.0) * self.grid.pitch
        free, exterior = self.grid.lookup(points)
        far &= free  # the ball argument makes far voxels free; this only guards against rounding
        inside = ~exterior
        near = np.flatnonzero(~far)
        for start in range(0, len(near), RAY_CHUNK):
            chunk = near[start : start + RAY_CHUNK]
            inside[chunk] = self._near_inside(points[chunk], closest[chunk])
        self.tally.points += len(points)
        self.tally.inside += int(inside.sum())
        self.tally.near += len(near)
        self._check(points, distance, far, inside)
        return inside

    def _near_inside(self, points: np.ndarray, closest: np.ndarray) -> np.ndarray:
        """Bool [M]: inside by the rays from points [M,3] near the mesh (see the module's step 3)."""
        away = points - closest
        length = np.linalg.norm(away, axis=1, keepdims=True)
        random = self._rng.normal(size=away.shape)
        away = np.where(
            length > 1e-12, away / np.maximum(length, 1e-300), random / np.linalg.norm(random, axis=1)[:, None]
        )
        reached, exterior = look_out(self.grid, self._segments, points, away[:, None, :])
        inside = ~exterior[:, 0]
        spread = np.flatnonzero(~reached[:, 0])
        if len(spread):
            rotations = Rotation.random(len(spread), random_state=self._rng).as_matrix()
            directions = np.einsum("pij,rj->pri", rotations, sphere_directions(self.n_rays))
            reached, exterior = look_out(self.grid, self._segments, points[spread], directions)
            inside[spread] = ~exterior.any(axis=1)
            self.tally.enclosed += int((~reached.any(axis=1)).sum())
        return inside

    def _check(self, points: np.ndarray, distance: np.ndarray, far: np.ndarray, inside: np.ndarray) -> None:
        """Count far samples whose sign flips at the check resolution, and under the winding number."""
        checked = far & (distance >= np.sqrt(3.0) * self.check_grid.pitch)
        free, exterior = self.check_grid.lookup(points[checked])
        self.tally.resolution_checked += int(free.sum())
        self.tally.resolution_flips += int(((~exterior) != inside[checked])[free].sum())
        candidates = np.flatnonzero(far)
        picked = self._rng.choice(candidates, min(len(candidates), WINDING_CHECKS), replace=False)
        w = np.abs(winding_number(self.vertices, self.surface.faces, points[picked]))
        self.tally.winding_checked += len(picked)
        self.tally.winding_flips += int(((w > 0.5) != inside[picked]).sum())
