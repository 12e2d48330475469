"""How much a candidate view would show: visibility of the current mesh, and the scores the strategies rank by.

The uncertainty-guided criterion (the paper's "guide the manipulator to find a next-best-view to
better reconstruct the uncertain part of the shape"): a candidate's score is the uncertain surface it
would see, sum over the current mesh's vertices visible from it of SDF variance x vertex area. If a
view told the encoder about what it shows, this is the variance it could remove. The variant
`unseen_uncertain_surface` counts only vertices no view taken so far has seen, for an encoder whose
variance does not drop on what it was shown. All scores: higher is better.
"""

from __future__ import annotations

import numpy as np
import trimesh

from ushape.data.cameras import camera_centre, project
from ushape.mesh.visibility import visible_points


def vertex_areas(
    vertices: np.ndarray,  # [V, 3]
    faces: np.ndarray,  # [F, 3]
) -> np.ndarray:  # [V]
    """The surface area each vertex stands for: a third of the area of every face it is a corner of."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    return np.bincount(np.asarray(faces).ravel(), np.repeat(area / 3.0, 3), minlength=len(vertices))


def visible_from(
    mesh: trimesh.Trimesh,
    K: np.ndarray,  # [C, 3, 3]
    world_to_cam: np.ndarray,  # [C, 4, 4]
    image_hw: np.ndarray,  # [C, 2] (H, W) of each camera's image
    tolerance: float = 1e-2,
) -> np.ndarray:  # [C, V] bool
    """Which vertices each camera sees: in front of it, inside its image, and first on the ray from its centre."""
    vertices = np.asarray(mesh.vertices, np.float64)
    seen = np.zeros((len(K), len(vertices)), dtype=bool)
    for c, (intrinsics, extrinsics, (h, w)) in enumerate(zip(K, world_to_cam, image_hw)):
        pixels, depth = project(vertices, intrinsics, extrinsics)
        framed = (depth > 0) & (pixels[:, 0] >= 0) & (pixels[:, 0] < w) & (pixels[:, 1] >= 0) & (pixels[:, 1] < h)
        if framed.any():
            seen[c, framed] = visible_points(mesh, vertices[framed], camera_centre(extrinsics), tolerance)
    return seen


def uncertain_surface(
    visible: np.ndarray,  # [C, V] bool
    variance: np.ndarray,  # [V] SDF variance at each vertex
    area: np.ndarray,  # [V]
) -> np.ndarray:  # [C]
    """Sum over the vertices each candidate sees of variance x area: the uncertain surface in its view."""
    return visible.astype(np.float64) @ (np.asarray(variance, np.float64) * np.asarray(area, np.float64))


def unseen_uncertain_surface(
    visible: np.ndarray,  # [C, V] bool
    variance: np.ndarray,  # [V]
    area: np.ndarray,  # [V]
    seen: np.ndarray,  # [V] bool: seen by a view already taken
) -> np.ndarray:  # [C]
    """`uncertain_surface` over the vertices no view taken so far has seen."""
    return uncertain_surface(visible & ~np.asarray(seen, bool)[None], variance, area)


def angular_gap(
    directions: np.ndarray,  # [C, 3] from the object's centre to each candidate camera
    taken: list[int],
) -> np.ndarray:  # [C] radians
    """Each candidate's angle to the nearest view taken (pi when none is): the farthest-view criterion."""
    if not taken:
        return np.full(len(directions), np.pi)
    unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    cos = np.clip(unit @ unit[taken].T, -1.0, 1.0)  # [C, T]
    return np.arccos(cos).min(axis=1)
