"""Inside or outside a real CAD mesh: the generalised winding number, with ray visibility where it cannot decide.

Real meshes are unions of parts, some closed, some open sheets, with faces duplicated (ShapeNet
stores many faces twice, once per side), wound inconsistently and meeting at non-manifold edges.

1. Clean: merge coincident vertices, drop degenerate and duplicate faces (a face stored twice
   with opposite winding would cancel itself in the winding number).
2. Orient: split the faces into patches joined across manifold edges and make each patch's
   winding consistent. A closed patch is turned to enclose positive volume; an open patch
   faces the side from which more rays, cast from points on it, escape to infinity. An open
   patch no ray escapes from on either side is hidden inside the model and dropped.
3. Winding number w of the oriented surface at each point (libigl's fast winding number: on
   a chair within 0.006 of the exact one and 1.5x faster). For a union of closed parts w
   counts the parts around the point, so a compartment between closed parts is outside
   however deep it is, which no escape threshold gets right (issue #18). A surface with small
   holes degrades gracefully (w stays near 1 inside).
4. Where |w| is undecided (between 1/4 and 3/4: beside a bare sheet, near a large opening)
   the ray-escape test decides: inside if fewer than 5% of the rays escape. Rays are cast only
   from points with |w| > 1/4 (about 30% of a chair's samples), which also measures how
   enclosed the inside points really are.

What no test of the mesh alone can know is the modeller's intent where much of a surface is
missing: a chair whose back was never modelled is a solid chair to the eye and a hollow shell
to a flood-filled voxelisation. This method fills what the surface mostly surrounds (|w| >= 3/4),
as it does a seat whose rim has holes. `SignTally` counts, per mesh, the points whose sign
needed that judgement (confidence) and what share of rays leaves from inside points (leak).
"""

from __future__ import annotations

from dataclasses import dataclass

import igl
import numpy as np
import trimesh
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial.transform import Rotation

WINDING_BAND = (0.25, 0.75)  # |w| inside this band: the winding number leaves the decision to rays
INSIDE_ESCAPE = 0.05  # in the band, inside if fewer than this share of rays escape
CLEARLY_OPEN = 0.25  # in the band with at least this share of rays escaping: plainly outside (beside a sheet)
RAY_CHUNK = 8192  # points per Embree batch: n_rays x this many rays stay ~100 MB
VOTE_POINTS, VOTE_RAYS = 32, 16  # per open patch: surface points, rays per side of each point
VOTE_BUDGET = 65_536  # at most this many vote points in all: a soup of many open patches gets fewer each (>= 4)
VOTE_OFFSET = 1e-5  # ray origins this far (x model extent) off the patch, clear of its own faces


def clean_triangles(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(vertices [V',3], faces [F',3]): coincident vertices merged, degenerate and duplicate faces dropped."""
    mesh = trimesh.Trimesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), process=False)
    mesh.merge_vertices()
    faces = np.asarray(mesh.faces, np.int64)
    corners = mesh.vertices[faces]
    doubled_area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    distinct = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    faces = faces[distinct & (doubled_area > 1e-12 * max(float(doubled_area.max(initial=0.0)), 1e-300))]
    _, first = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
    return np.ascontiguousarray(mesh.vertices, np.float64), np.ascontiguousarray(faces[np.sort(first)])


def _edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(undirected edge id [3F] of each face's edges (v0v1, v1v2, v2v0), count [E] of faces per edge)."""
    directed = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    _, edge_id, counts = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True, return_counts=True)
    return edge_id.reshape(-1), counts


def orientable_patches(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(patch label [F], flip [F], closed [P]) for faces [F,3] joined across edges shared by exactly two faces.

    Reversing the faces marked `flip` makes every patch's winding consistent (whenever the patch
    is orientable); a patch is closed when each of its edges belongs to two of its faces.
    """
    n_faces = len(faces)
    edge_id, counts = _edges(faces)
    forward = (faces[:, [0, 1, 2]] < faces[:, [1, 2, 0]]).reshape(-1)
    owner = np.repeat(np.arange(n_faces), 3)
    manifold = np.flatnonzero(counts[edge_id] == 2)
    manifold = manifold[np.argsort(edge_id[manifold], kind="stable")]
    a, b = manifold[0::2], manifold[1::2]
    pairs, first = np.unique(np.stack([owner[a], owner[b]], axis=1), axis=0, return_index=True)
    # Two faces agree when they run along their shared edge in opposite directions.
    disagree = (forward[a] == forward[b])[first]
    graph = sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n_faces, n_faces))
    n_patches, labels = csgraph.connected_components(graph, directed=False)
    flip = _tree_parity(n_faces, pairs, disagree, labels, n_patches)
    patch_edge = np.unique(np.stack([labels[owner], edge_id], axis=1), axis=0, return_counts=True)
    closed = np.ones(n_patches, bool)
    closed[patch_edge[0][patch_edge[1] != 2, 0]] = False
    return labels, flip, closed


def _tree_parity(n: int, pairs: np.ndarray, disagree: np.ndarray, labels: np.ndarray, n_patches: int) -> np.ndarray:
    """Bool [n]: parity of disagreeing pairs on the breadth-first tree path from each node to its patch's root."""
    root = n  # a virtual node joined to one face of every patch makes the forest one tree
    starts = np.unique(labels, return_index=True)[1]
    rows = np.concatenate([pairs[:, 0], pairs[:, 1], np.full(n_patches, root)])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0], starts])
    parity = np.concatenate([disagree, disagree, np.zeros(n_patches, bool)]).astype(np.float64)
    tree = sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n + 1, n + 1))
    _, parent = csgraph.breadth_first_order(tree, root, directed=True, return_predecessors=True)
    parent[root] = root
    lookup = sparse.csr_matrix((parity + 1.0, (rows, cols)), shape=(n + 1, n + 1))
    acc = np.zeros(n + 1, bool)
    acc[:n] = np.asarray(lookup[parent[:n], np.arange(n)]).reshape(-1) == 2.0
    ancestor = parent.copy()
    while np.any(ancestor != root):  # pointer jumping: log(depth) vector steps instead of a walk per face
        acc, ancestor = acc ^ acc[ancestor], ancestor[ancestor]
    return acc[:n]


@dataclass(frozen=True)
class OrientedSurface:
    """Faces [F',3] (indices into the cleaned vertices) oriented outward, and what it took to get them."""

    faces: np.ndarray
    patches: int
    closed_patches: int
    flipped_patches: int
    hidden_patches: int


def hemisphere_directions(normals: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Directions [P,n,3]: n near-uniform unit vectors on the hemisphere around each normal [P,3], randomly spun."""
    i = np.arange(n) + 0.5
    z = 1.0 - i / n
    azimuth = np.pi * (1.0 + 5.0**0.5) * i
    r = np.sqrt(1.0 - z**2)
    local = np.stack([r * np.cos(azimuth), r * np.sin(azimuth), z], axis=1)
    helper = rng.normal(size=normals.shape)  # a random tangent per point spins its hemisphere
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    return np.einsum("rk,pkj->prj", local, np.stack([t1, t2, normals], axis=1))


def orient_surface(vertices: np.ndarray, faces: np.ndarray, rng: np.random.Generator) -> OrientedSurface:
    """Outward orientation of cleaned faces [F,3]: closed patches by signed volume, open ones by escaping rays."""
    labels, flip, closed = orientable_patches(faces)
    faces = faces.copy()
    faces[flip] = faces[flip][:, ::-1]
    corners = vertices[faces]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = np.linalg.norm(cross, axis=1) / 2
    volume = np.bincount(labels, np.einsum("ij,ij->i", corners[:, 0], cross) / 6.0, minlength=len(closed))
    turn = closed & (volume < 0)
    keep = np.ones(len(closed), bool)
    open_ids = np.flatnonzero(~closed)
    if len(open_ids):
        front, back = _escapes_per_side(vertices, faces, labels, open_ids, area, cross / (2 * area[:, None]), rng)
        turn[open_ids] = back > front
        keep[open_ids[(front == 0) & (back == 0)]] = False
    faces[turn[labels]] = faces[turn[labels]][:, ::-1]
    return OrientedSurface(
        faces=np.ascontiguousarray(faces[keep[labels]]),
        patches=len(closed),
        closed_patches=int(closed.sum()),
        flipped_patches=int(turn.sum()),
        hidden_patches=int((~keep).sum()),
    )


def _escapes_per_side(vertices, faces, labels, open_ids, area, normals, rng) -> tuple[np.ndarray, np.ndarray]:
    """(front, back) [len(open_ids)]: rays escaping from up to VOTE_POINTS area-weighted points of each open patch."""
    in_open = np.flatnonzero(np.isin(labels, open_ids))
    in_open = in_open[np.argsort(labels[in_open], kind="stable")]
    cumulative = np.cumsum(area[in_open])
    patch_end = cumulative[np.searchsorted(labels[in_open], open_ids, side="right") - 1]
    patch_start = patch_end - np.bincount(labels[in_open], area[in_open])[open_ids]
    per_patch = int(np.clip(VOTE_BUDGET // len(open_ids), 4, VOTE_POINTS))
    owner = np.repeat(np.arange(len(open_ids)), per_patch)
    # Area-weighted faces within each patch: uniform positions along the patch's stretch of the cumulative area.
    target = patch_start[owner] + rng.random(len(owner)) * (patch_end - patch_start)[owner]
    face = in_open[np.minimum(np.searchsorted(cumulative, target), len(in_open) - 1)]
    u, v = rng.random(len(face)), rng.random(len(face))
    fold = u + v > 1
    u[fold], v[fold] = 1 - u[fold], 1 - v[fold]
    tri = vertices[faces[face]]
    points = tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])
    normal = normals[face]
    offset = VOTE_OFFSET * float(np.ptp(vertices, axis=0).max())
    intersector = trimesh.Trimesh(vertices, faces, process=False).ray
    counts = []
    for side in (1.0, -1.0):
        directions = hemisphere_directions(side * normal, VOTE_RAYS, rng).reshape(-1, 3)
        origins = np.repeat(points + side * offset * normal, VOTE_RAYS, axis=0)
        hit = intersector.intersects_any(origins, directions).reshape(len(points), VOTE_RAYS)
        counts.append(np.bincount(owner, (~hit).sum(axis=1), minlength=len(open_ids)))
    return counts[0], counts[1]


def sphere_directions(n: int) -> np.ndarray:
    """n near-uniform unit vectors [n,3] on the sphere (Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    polar = np.arccos(1.0 - 2.0 * i / n)
    azimuth = np.pi * (1.0 + 5.0**0.5) * i
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1)


def escape_fraction(mesh: trimesh.Trimesh, points: np.ndarray, n_rays: int, rng: np.random.Generator) -> np.ndarray:
    """Fraction [N] of n_rays rays from each point [N,3] that hit no triangle (orientation-free)."""
    if n_rays < 1:
        raise ValueError(f"n_rays must be at least 1, got {n_rays}")
    base = sphere_directions(n_rays)
    intersector = mesh.ray
    out = np.empty(len(points))
    for start in range(0, len(points), RAY_CHUNK):
        chunk = points[start : start + RAY_CHUNK]
        # A random rotation per point keeps neighbouring points from sharing blind spots.
        rotations = Rotation.random(len(chunk), random_state=rng).as_matrix()
        directions = np.einsum("pij,rj->pri", rotations, base).reshape(-1, 3)
        origins = np.repeat(chunk, n_rays, axis=0)
        hit = intersector.intersects_any(origins, directions).reshape(len(chunk), n_rays)
        out[start : start + len(chunk)] = 1.0 - hit.mean(axis=1)
    return out


@dataclass
class SignTally:
    """Running counts over every point classified: how often the winding number needed help, how sure the result is."""

    points: int = 0
    inside: int = 0
    undecided: int = 0  # 1/4 < |w| < 3/4: the rays decided
    confident: int = 0  # both tests clear: |w| <= 1/4; |w| >= 3/4 and no ray escapes; undecided and >= 1/4 escape
    inside_escape: float = 0.0  # sum of the escape fractions of inside points

    def add(self, w: np.ndarray, escape: np.ndarray, inside: np.ndarray) -> None:
        lo, hi = WINDING_BAND
        undecided = (w > lo) & (w < hi)
        confident = (w <= lo) | ((w >= hi) & (escape == 0)) | (undecided & (escape >= CLEARLY_OPEN))
        self.points += len(w)
        self.inside += int(inside.sum())
        self.undecided += int(undecided.sum())
        self.confident += int(confident.sum())
        self.inside_escape += float(escape[inside].sum())

    def share(self, count: float) -> float:
        return count / self.points if self.points else 0.0

    @property
    def leak(self) -> float:
        """Mean share of rays escaping from inside points: 0 when every inside point is enclosed."""
        return self.inside_escape / self.inside if self.inside else 0.0


class MeshSigns:
    """Inside test [N] for points [N,3] of a real mesh: winding number, with ray escape in its undecided band."""

    def __init__(self, mesh: trimesh.Trimesh, n_rays: int = 32, seed: int = 0) -> None:
        self.n_rays = int(n_rays)
        self._rng = np.random.default_rng(seed)
        self.vertices, faces = clean_triangles(mesh.vertices, mesh.faces)
        if len(faces) == 0:
            raise ValueError("the mesh has no non-degenerate faces")
        self.surface = orient_surface(self.vertices, faces, self._rng)
        self.all_faces = faces  # rays and distances see hidden faces too
        used = self.vertices[np.unique(faces)]
        self._bounds = (used.min(axis=0), used.max(axis=0))
        self._intersect = trimesh.Trimesh(self.vertices, faces, process=False)
        self.tally = SignTally()

    def winding_number(self, points: np.ndarray) -> np.ndarray:
        """Generalised winding number [N] of the oriented surface at points [N,3] (1 inside a closed part)."""
        points = np.ascontiguousarray(points, np.float64)
        if len(self.surface.faces) == 0 or len(points) == 0:
            return np.zeros(len(points))
        return igl.fast_winding_number(self.vertices, self.surface.faces, points)

    def inside(self, points: np.ndarray) -> np.ndarray:
        """Bool [N]: |w| >= 3/4, or 1/4 < |w| < 3/4 and fewer than INSIDE_ESCAPE of n_rays rays escape.

        |w| rather than w: a patch the orientation step got backwards still encloses its inside.
        Rays are cast from every point with |w| > 1/4, inside or undecided, so the tally can say
        how many inside points the surface really encloses (no ray escapes).
        """
        points = np.asarray(points, np.float64)
        # Outside the bounding box the whole surface lies in a half-space, so |w| <= 1/2 and at least
        # half the rays escape: outside by either test. Skipping them saves 15-45% of a model's samples.
        w = np.zeros(len(points))
        boxed = np.flatnonzero(np.all((points >= self._bounds[0]) & (points <= self._bounds[1]), axis=1))
        w[boxed] = np.abs(self.winding_number(points[boxed]))
        lo, hi = WINDING_BAND
        cast = np.flatnonzero(w > lo)
        escape = np.zeros(len(points))
        escape[cast] = escape_fraction(self._intersect, points[cast], self.n_rays, self._rng)
        inside = np.where((w > lo) & (w < hi), escape < INSIDE_ESCAPE, w >= hi)
        self.tally.add(w, escape, inside)
        return inside
