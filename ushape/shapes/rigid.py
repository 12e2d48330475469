"""Rotation matrices and the frame of a beam between two points (raw, y-up, front +Z)."""

from __future__ import annotations

import numpy as np


def rot_x(angle: float) -> np.ndarray:
    """[3,3] rotation by `angle` radians about +X (right-handed)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> np.ndarray:
    """[3,3] rotation by `angle` radians about +Y (right-handed)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def frame_along(direction: np.ndarray, hint: np.ndarray | None = None) -> np.ndarray:
    """[3,3] rotation whose local +Y is `direction` and local +X is `hint` made orthogonal to it.

    Columns are the local axes in the parent frame, so `R @ q` maps local to parent.
    Without a hint, +X is used unless the direction is nearly parallel to it, then +Z.
    """
    y = np.asarray(direction, dtype=np.float64)
    norm = np.linalg.norm(y)
    if norm == 0.0:
        raise ValueError("frame_along needs a non-zero direction (two distinct end points)")
    y = y / norm
    if hint is None:
        hint = np.array([1.0, 0.0, 0.0]) if abs(y[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = np.asarray(hint, dtype=np.float64) - np.dot(hint, y) * y
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("frame_along: the hint is parallel to the direction; pass a different hint")
    x = x / np.linalg.norm(x)
    z = np.cross(x, y)
    return np.stack([x, y, z], axis=1)
