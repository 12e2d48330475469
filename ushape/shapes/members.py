"""Structural members shared by chairs and tables: legs, posts and stretchers between two points."""

from __future__ import annotations

import numpy as np

from ushape.shapes.primitives import Box, CappedCone, Capsule, Primitive

MEMBER_PROFILES = ("square", "round", "tapered", "tube")


def rod(a, b, thickness: float, profile: str, taper: float = 1.0) -> Primitive:
    """Member from a to b of the given thickness: square beam, round rod (radius scaled by `taper` at a) or tube."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if profile == "square":
        # Square the section to the floor: upright members face x, lying ones keep a vertical side.
        upright = abs(b[1] - a[1]) > 0.7 * np.linalg.norm(b - a)
        return Box.between(a, b, thickness, thickness, hint=(1.0, 0.0, 0.0) if upright else (0.0, 1.0, 0.0))
    if profile == "tube":
        return Capsule(a=a, b=b, radius=thickness / 2)
    if profile in ("round", "tapered"):
        return CappedCone(a=a, b=b, radius_a=thickness / 2 * taper, radius_b=thickness / 2)
    raise ValueError(f"unknown member profile {profile!r}; expected one of {MEMBER_PROFILES}")
