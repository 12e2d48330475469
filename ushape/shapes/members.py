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


def splayed_legs(anchors: np.ndarray, top_y: float, splay_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(tops [K,3], feet [K,3]) of legs from (x, z) anchors [K,2] at top_y, feet splayed outwards onto y = 0."""
    spread = np.tan(np.radians(splay_deg)) * top_y
    radial = anchors / np.linalg.norm(anchors, axis=1, keepdims=True)
    tops = np.stack([anchors[:, 0], np.full(len(anchors), top_y), anchors[:, 1]], axis=1)
    feet = np.stack(
        [anchors[:, 0] + spread * radial[:, 0], np.zeros(len(anchors)), anchors[:, 1] + spread * radial[:, 1]], axis=1
    )
    return tops, feet
