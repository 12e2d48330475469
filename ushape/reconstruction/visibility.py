"""Which mesh vertices an input view sees, and whether the uncertainty sits on the ones it does not.

The paper's figures show uncertainty on the parts a view hides or crops away. For a view with a known
camera (a render of the world, see `view_depth.view_camera`) this measures it: every vertex is ray cast
from the camera centre against the reconstructed mesh itself, and the median std of the hidden vertices
is compared with that of the visible ones (> 1: the view's unseen parts are the less certain ones).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import trimesh

from ushape.data.cameras import camera_centre, project
from ushape.mesh.visibility import median_ratio, visible_points
from ushape.refinement.views import ObservedView

# How far behind the reconstructed surface a point may lie and still count as seen (SDF units; the
# refinement's free-space margin): the skin under a visible surface is pinned with it.
SEEN_TOLERANCE = 0.03


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


def seen_by_views(
    mesh: trimesh.Trimesh,
    points: np.ndarray,  # [P, 3]
    views: Sequence[ObservedView],
    tolerance: float = SEEN_TOLERANCE,
) -> np.ndarray:  # [P] bool
    """True where some view saw the point: it projects in front of the camera onto a pixel that view observed
    (a crop's cut-away part and the image's outside are not), and the ray to it does not meet `mesh` (the
    reconstruction) more than `tolerance` before it."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    seen = np.zeros(len(points), dtype=bool)
    for view in views:
        uv, z = project(points, np.asarray(view.K), np.asarray(view.world_to_cam))
        h, w = view.image_hw
        col, row = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
        inside = (z > 0) & (row >= 0) & (row < h) & (col >= 0) & (col < w)
        observed = view.seen().numpy()
        candidate = np.flatnonzero(inside & ~seen)
        candidate = candidate[observed[row[candidate], col[candidate]]]
        if len(candidate) and len(mesh.faces):
            unblocked = visible_points(mesh, points[candidate], camera_centre(view.world_to_cam), tolerance)
            candidate = candidate[unblocked]
        seen[candidate] = True
    return seen
