"""Small shaded pictures of meshes for TensorBoard, from one fixed three-quarter view."""

from __future__ import annotations

import numpy as np
import trimesh

from ushape.data.cameras import look_at
from ushape.data.rendering import on_white, render_mesh

# Three-quarter view from above that frames the unit sphere of the normalised frame.
PREVIEW_VIEW = {"azimuth_deg": 45.0, "elevation_deg": 25.0, "distance": 2.6, "fov_deg": 49.13}


def preview_image(mesh: trimesh.Trimesh | None, image_size: int = 128) -> np.ndarray:
    """RGB uint8 [S, S, 3] of the mesh on white; a blank (white) picture when mesh is None."""
    if mesh is None or len(mesh.faces) == 0:
        return np.full((image_size, image_size, 3), 255, np.uint8)
    return on_white(render_mesh(mesh, *look_at(image_size=image_size, **PREVIEW_VIEW), image_size)["rgba"])
