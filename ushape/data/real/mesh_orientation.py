"""Outward orientation of a real CAD mesh's faces, and the generalised winding number it gives.

Real meshes are unions of parts, some closed, some open sheets, with faces duplicated (ShapeNet
stores many faces twice, once per side), wound inconsistently and meeting at non-manifold edges.

1. Clean: merge coincident vertices, drop degenerate and duplicate faces (a face stored twice
   with opposite winding would cancel itself in the winding number).
2. Orient: split the faces into patches joined across manifold edges and make each patch's
   winding consistent. A closed patch is turned to enclose positive volume; an open patch
   faces the side from which more rays, cast from points on it, escape to infinity. An open
   patch no ray escapes from on either side is hidden inside the model and dropped.
3. Winding number w of the oriented surface (libigl's fast winding number): about 1 inside a
   closed part, 0 outside.

The signs themselves come from reachability (`ushape.data.real.mesh_signs`); the winding number is
the second opinion whose disagreement lowers a mesh's sign confidence.
"""

from __future__ import annotations

from dataclasses import dataclass

import igl
import numpy as np
import trimesh
from scipy import sparse
from scipy.sparse import csgraph

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


def winding_number(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Generalised winding number [N] of oriented faces [F,3] at points [N,3] (1 inside a closed part)."""
    points = np.ascontiguousarray(points, np.float64)
    if len(faces) == 0 or len(points) == 0:
        return np.zeros(len(points))
    return igl.fast_winding_number(np.ascontiguousarray(vertices, np.float64), np.ascontiguousarray(faces), points)
