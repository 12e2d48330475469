"""Which points on a mesh a camera sees: a ray from the camera centre to each point, first hit on the mesh."""

from __future__ import annotations

import numpy as np
import trimesh


def visible_points(
    mesh: trimesh.Trimesh,
    points: np.ndarray,  # [P, 3] on (or within tolerance of) the mesh surface
    centre: np.ndarray,  # [3] camera centre
    tolerance: float = 1e-2,
) -> np.ndarray:  # [P] bool
    """True where the first hit of the ray from `centre` towards a point is (within tolerance) that point."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    offsets = points - np.asarray(centre, dtype=np.float64)
    distance = np.linalg.norm(offsets, axis=1)
    if np.any(distance <= tolerance):
        raise ValueError("the camera centre is on the mesh; visibility is undefined")
    directions = offsets / distance[:, None]
    origins = np.broadcast_to(np.asarray(centre, dtype=np.float64), points.shape)
    hits, rays, _ = mesh.ray.intersects_location(origins, directions, multiple_hits=False)
    first = np.full(len(points), np.inf)
    first[rays] = np.linalg.norm(hits - origins[rays], axis=1)
    return first >= distance - tolerance


def median_ratio(
    values: np.ndarray,  # [P]
    over: np.ndarray,  # [P] bool: the numerator's points
    under: np.ndarray,  # [P] bool: the denominator's points
    under_values: np.ndarray | None = None,  # [P] the denominator's values (default: `values`)
) -> float | None:
    """median(values[over]) / median(under_values[under]); None if a set is empty or the denominator is 0."""
    under_values = values if under_values is None else under_values
    over, under = np.asarray(over, dtype=bool), np.asarray(under, dtype=bool)
    if not over.any() or not under.any():
        return None
    denominator = float(np.median(np.asarray(under_values, dtype=np.float64)[under]))
    if denominator <= 0:
        return None
    return float(np.median(np.asarray(values, dtype=np.float64)[over])) / denominator
