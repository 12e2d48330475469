"""Which mesh vertices an input view sees, and whether the uncertainty sits on the ones it does not.

The paper's figures show uncertainty on the parts a view hides or crops away. For a view with a known
camera (a render of the world, see `pipeline.view_camera`) this measures it: every vertex is ray cast
from the camera centre against the reconstructed mesh itself, and the median std of the hidden vertices
is compared with that of the visible ones (> 1: the view's unseen parts are the less certain ones).
"""

from __future__ import annotations

import numpy as np
import trimesh

from ushape.data.cameras import camera_centre


def visible_vertices(mesh: trimesh.Trimesh, centre: np.ndarray, tolerance: float = 1e-2) -> np.ndarray:
    """[V] bool: the first hit of the ray from `centre` [3] towards each vertex is (within tolerance) that vertex."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    offsets = vertices - np.asarray(centre, dtype=np.float64)
    distance = np.linalg.norm(offsets, axis=1)
    if np.any(distance <= tolerance):
        raise ValueError("the camera centre is on the mesh; visibility is undefined")
    directions = offsets / distance[:, None]
    origins = np.broadcast_to(np.asarray(centre, dtype=np.float64), vertices.shape)
    hits, rays, _ = mesh.ray.intersects_location(origins, directions, multiple_hits=False)
    first = np.full(len(vertices), np.inf)
    first[rays] = np.linalg.norm(hits - origins[rays], axis=1)
    return first >= distance - tolerance


def hidden_over_visible(mesh: trimesh.Trimesh, std: np.ndarray, world_to_cam: np.ndarray) -> dict:
    """{"visible_vertices", "hidden_vertices", "std_hidden_over_visible"} (ratio of medians; None if either set is empty)."""
    visible = visible_vertices(mesh, camera_centre(world_to_cam))
    std = np.asarray(std, dtype=np.float64)
    ratio = None
    if visible.any() and (~visible).any() and np.median(std[visible]) > 0:
        ratio = float(np.median(std[~visible]) / np.median(std[visible]))
    return {"visible_vertices": int(visible.sum()), "hidden_vertices": int((~visible).sum()),
            "std_hidden_over_visible": ratio}
