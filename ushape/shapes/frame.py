"""DeepSDF's normalised frame for a union of primitives, and the minimum part thickness in it.

normalised = (raw - centre) / scale, with centre the bounding-box centre of the surface and
scale = 1.03 * (largest distance of the surface from the centre), as DeepSDF normalises meshes.
Signed distances scale the same way: sdf_normalised(x) = sdf_raw(centre + scale * x) / scale.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ushape.shapes.primitives import Primitive

# DeepSDF's buffer: the surface ends at radius 1/1.03 of the unit sphere.
SPHERE_BUFFER = 1.03
# Thinnest dimension of any primitive in normalised units: 3.8 cells of a 256 grid over [-1, 1],
# 2.9 cells at 192, so marching cubes does not break legs, slats and tubes.
MIN_THICKNESS = 0.03


def union_aabb(primitives: Sequence[Primitive]) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding box (lo [3], hi [3]) of a union of primitives, raw frame."""
    if not primitives:
        raise ValueError("union_aabb needs at least one primitive")
    boxes = [p.aabb() for p in primitives]
    return np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)


def normalisation(primitives: Sequence[Primitive]) -> tuple[np.ndarray, float]:
    """(centre [3], scale) mapping the union into the unit sphere with DeepSDF's 1.03 buffer.

    The farthest surface point of a union is the farthest point of one of its members (a point
    strictly inside another member would make that member reach farther), so the maximum of the
    members' farthest distances is exact.
    """
    lo, hi = union_aabb(primitives)
    centre = (lo + hi) / 2.0
    radius = max(p.max_distance(centre) for p in primitives)
    return centre, SPHERE_BUFFER * radius


def thicken_to_normalised(primitives: Sequence[Primitive], min_thickness: float = MIN_THICKNESS):
    """Thicken members thinner than `min_thickness` normalised units; returns (primitives, centre, scale).

    Thickening grows the shape and so its scale; a few passes settle it (each grows it less).
    """
    prims = list(primitives)
    centre, scale = normalisation(prims)
    for _ in range(4):
        prims = [p.thickened(min_thickness * scale) for p in prims]
        new_centre, new_scale = normalisation(prims)
        settled = new_scale <= scale * (1.0 + 1e-9)
        centre, scale = new_centre, new_scale
        if settled:
            break
    return prims, centre, scale
