"""Exact signed distances to 2D profiles (rounded rectangle, ellipse) for extruded solids."""

from __future__ import annotations

import numpy as np

# Fixed-point iterations of the curvature-circle method; 6 match a brute-force distance to 1e-6
# of the semi-major axis for aspect ratios up to 10 (see tests/shapes/test_primitives.py).
_ELLIPSE_ITERATIONS = 6


def rounded_rect_sdf(x: np.ndarray, z: np.ndarray, half_x: float, half_z: float, corner: float) -> np.ndarray:
    """[N],[N] -> [N] signed distance to a rectangle (half sizes) with corners rounded by `corner`."""
    dx = np.abs(x) - (half_x - corner)
    dz = np.abs(z) - (half_z - corner)
    outside = np.hypot(np.maximum(dx, 0.0), np.maximum(dz, 0.0))
    return outside + np.minimum(np.maximum(dx, dz), 0.0) - corner


def ellipse_closest_point(x: np.ndarray, z: np.ndarray, a: float, b: float) -> tuple[np.ndarray, np.ndarray]:
    """[N],[N] -> nearest point ([N],[N]) on the ellipse x^2/a^2 + z^2/b^2 = 1, inside or out.

    Iterates on the ellipse's evolute: each step moves the guess along the local circle of
    curvature towards the query point (a well-known robust scheme, no root finding).
    """
    px, pz = np.abs(x), np.abs(z)
    tx = np.full(px.shape, np.sqrt(0.5))
    tz = np.full(px.shape, np.sqrt(0.5))
    k = a * a - b * b
    for _ in range(_ELLIPSE_ITERATIONS):
        ex = k * tx**3 / a
        ez = -k * tz**3 / b
        r = np.hypot(a * tx - ex, b * tz - ez)
        qx, qz = px - ex, pz - ez
        q = np.maximum(np.hypot(qx, qz), 1e-300)
        tx = np.clip((qx * r / q + ex) / a, 0.0, 1.0)
        tz = np.clip((qz * r / q + ez) / b, 0.0, 1.0)
        t = np.hypot(tx, tz)
        # Both clipped to zero only at the centre of a circle-like ellipse; any direction then
        # works, and the minor axis is the right one for a true ellipse.
        centre = t == 0.0
        t[centre] = 1.0
        tx, tz = tx / t, tz / t
        tx[centre], tz[centre] = (1.0, 0.0) if a < b else (0.0, 1.0)
    return np.copysign(a * tx, x), np.copysign(b * tz, z)


def ellipse_sdf(x: np.ndarray, z: np.ndarray, a: float, b: float) -> np.ndarray:
    """[N],[N] -> [N] signed distance to the filled ellipse with semi-axes a (x) and b (z)."""
    cx, cz = ellipse_closest_point(x, z, a, b)
    dist = np.hypot(x - cx, z - cz)
    inside = (x / a) ** 2 + (z / b) ** 2 < 1.0
    return np.where(inside, -dist, dist)
