"""A chair back (posts, panel, rails, slats, spine) laid out in the tilted back plane (raw frame).

The back plane passes through (0, seat height, mount.z) and leans backwards by the tilt: a point
(x, s) of the plane is origin + x * X + s * up, with up = (0, cos tilt, -sin tilt).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ushape.shapes.members import rod
from ushape.shapes.primitives import Box, Capsule, Primitive, Slab
from ushape.shapes.rigid import rot_x


@dataclass(frozen=True)
class BackMount:
    """Where the back stands: posts at x = +-x (or a panel that wide) in the plane through z."""

    x: float
    z: float
    posts: str | None  # "square", "round", "tube", or None for a panel held by a spine
    post_thickness: float


class _BackPlane:
    """Points and in-plane boxes of the tilted back plane."""

    def __init__(self, style: dict, mount: BackMount) -> None:
        tilt = math.radians(style["back_tilt_deg"])
        self.origin = np.array([0.0, style["seat_height"], mount.z])
        self.rotation = rot_x(-tilt)  # columns: X, up, forward normal
        self.up = self.rotation[:, 1]
        self.tilt = tilt

    def point(self, x: float, s: float) -> np.ndarray:
        return self.origin + np.array([x, 0.0, 0.0]) + s * self.up

    def board(self, x: float, s_lo: float, s_hi: float, half_width: float, thickness: float) -> Box:
        """Flat board centred at x spanning heights s_lo..s_hi of the plane."""
        return Box(
            centre=self.point(x, (s_lo + s_hi) / 2),
            rotation=self.rotation,
            half=(half_width, (s_hi - s_lo) / 2, thickness / 2),
            radius=min(thickness / 2, 0.004),
        )


def _panel(style: dict, plane: _BackPlane, half_width: float, s_lo: float, s_hi: float) -> Slab:
    """Solid back: a rectangular, rounded or oval board; the slab's thickness axis is the plane normal."""
    thickness, half_h = style["back_thickness"], (s_hi - s_lo) / 2
    shape = style["back_panel_shape"]
    corner = {"rect": min(0.01, half_h), "rounded": 0.35 * min(half_width, half_h), "oval": 0.0}[shape]
    x_axis, normal, up = plane.rotation[:, 0], plane.rotation[:, 2], plane.up
    return Slab(
        centre=plane.point(0.0, (s_lo + s_hi) / 2),
        rotation=np.stack([x_axis, normal, -up], axis=1),
        half_x=half_width,
        half_z=half_h,
        half_height=thickness / 2,
        profile="ellipse" if shape == "oval" else "rect",
        corner_radius=corner,
        edge_radius=min(0.3 * thickness, 0.01),
    )


def _rail(plane: _BackPlane, mount: BackMount, half_width: float, s_lo: float, s_hi: float, thick: float):
    if mount.posts == "tube":
        s = (s_lo + s_hi) / 2
        return Capsule(a=plane.point(-half_width, s), b=plane.point(half_width, s), radius=mount.post_thickness / 2)
    return plane.board(0.0, s_lo, s_hi, half_width, thick)


def _slats(style: dict, plane: _BackPlane, half_width: float, s_lo: float, s_hi: float, thick: float):
    """Vertical slats between the rails at s_lo and s_hi, or horizontal ones stacked between them."""
    n = style["n_slats"]
    if style["slat_direction"] == "vertical":
        width = min(style["slat_width"], 1.6 * half_width / (n + 1))
        xs = [-half_width + (i + 1) * 2 * half_width / (n + 1) for i in range(n)]
        return [plane.board(x, s_lo, s_hi, width / 2, 0.7 * thick) for x in xs]
    pitch = (s_hi - s_lo) / (n + 1)
    height = min(style["slat_width"], 0.6 * pitch)
    centres = [s_lo + (i + 1) * pitch for i in range(n)]
    return [plane.board(0.0, s - height / 2, s + height / 2, half_width, 0.7 * thick) for s in centres]


def _spine(style: dict, plane: _BackPlane, s_top: float) -> list[Primitive]:
    """L-shaped bar from under the seat up the back plane, for backs without posts."""
    seat_bottom = style["seat_height"] - style["seat_thickness"]
    y_bar = seat_bottom - 0.01
    z_plane = plane.origin[2] + (style["seat_height"] - y_bar) * math.tan(plane.tilt)
    s_bar = (y_bar - style["seat_height"]) / math.cos(plane.tilt)
    bar_start = (0.0, y_bar, -style["seat_depth"] / 2 + 0.1)
    return [
        Box.between(bar_start, (0.0, y_bar, z_plane - 0.01), 0.06, 0.02, hint=(1.0, 0.0, 0.0)),
        plane.board(0.0, s_bar - 0.01, s_top, 0.03, 0.02),
    ]


def build_back(style: dict, mount: BackMount) -> list[Primitive]:
    """Primitives of a solid, slatted or open-frame back on the given mount."""
    if style["back"] not in ("solid", "slatted", "open_frame"):
        raise ValueError(f"unknown chair back {style['back']!r}; expected solid, slatted or open_frame")
    plane = _BackPlane(style, mount)
    top, gap, rail_h = style["back_height"], style["back_gap"] * style["back_height"], style["rail_height"]
    half_width = mount.x
    thick = float(np.clip(0.6 * style["back_thickness"], 0.015, 0.03))
    prims: list[Primitive] = []
    if mount.posts is not None:
        for x in (-half_width, half_width):
            low, high = plane.point(x, -style["seat_thickness"]), plane.point(x, top)
            prims.append(rod(low, high, mount.post_thickness, mount.posts))
    if style["back"] == "solid":
        prims.append(_panel(style, plane, half_width, gap, top))
    else:
        prims.append(_rail(plane, mount, half_width, top - rail_h, top, thick))
        prims.append(_rail(plane, mount, half_width, gap, gap + rail_h, thick))
        if style["back"] == "slatted":
            prims += _slats(style, plane, half_width, gap + rail_h / 2, top - rail_h / 2, thick)
        if mount.posts is None:
            prims += [plane.board(x, gap, top, 0.015, thick) for x in (-half_width + 0.015, half_width - 0.015)]
    if mount.posts is None:
        prims += _spine(style, plane, gap + min(0.08, (top - gap) / 2))
    return prims
