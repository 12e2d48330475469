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
from ushape.mesh.visibility import median_ratio, visible_points


def visible_vertices(mesh: trimesh.Trimesh, centre: np.ndarray, tolerance: float = 1e-2) -> np.ndarray:
    """[V] bool: the camera at `centre` [3] sees the vertex (see `ushape.mesh.visibility.visible_points`)."""
    return visible_points(mesh, mesh.vertices, centre, tolerance)


def hidden_over_visible(mesh: trimesh.Trimesh, std: np.ndarray, world_to_cam: np.ndarray) -> dict:
    """{"visible_vertices", "hidden_vertices", "std_hidden_over_visible"}: a ratio of medians (None: a set is empty)."""
    visible = visible_vertices(mesh, camera_centre(world_to_cam))
    ratio = median_ratio(np.asarray(std, dtype=np.float64), ~visible, visible)
    return {
        "visible_vertices": int(visible.sum()),
        "hidden_vertices": int((~visible).sum()),
        "std_hidden_over_visible": ratio,
    }
