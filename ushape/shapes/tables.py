"""A table's primitives from its style (raw frame: metres, y up, front +Z, top centred on x = z = 0).

The top's long side runs along x; trestle end frames stand at +-x.
"""

from __future__ import annotations

import math

import numpy as np

from ushape.shapes.members import rod, splayed_legs
from ushape.shapes.primitives import Box, CappedCone, Primitive, Slab

PART_ORDER = ("top", "legs", "apron", "stretchers", "shelf", "column", "base")


def _top(style: dict) -> Slab:
    t = style["top_thickness"]
    return Slab(
        centre=(0.0, style["table_height"] - t / 2, 0.0),
        half_x=style["top_length"] / 2,
        half_z=style["top_width"] / 2,
        half_height=t / 2,
        profile="rect" if style["top"] == "rectangular" else "ellipse",
        corner_radius=style["top_corner"],
        edge_radius=min(0.3 * t, 0.01),
    )


def _leg_anchors(style: dict, inset: float) -> np.ndarray:
    """[4,2] (x, z) of leg tops: front-left, front-right, back-left, back-right."""
    a, b = style["top_length"] / 2 - inset, style["top_width"] / 2 - inset
    if style["top"] == "rectangular":
        cut = style["top_corner"] * (1.0 - 1.0 / math.sqrt(2.0))
        a, b = a - cut, b - cut
    else:
        a, b = a / math.sqrt(2.0), b / math.sqrt(2.0)
    return np.array([[-a, b], [a, b], [-a, -b], [a, -b]])


_PAIRS = {"box": [(0, 1), (2, 3), (0, 2), (1, 3)], "H": [(0, 2), (1, 3)], "X": [(0, 3), (1, 2)]}


def _shelf(style: dict, front_right: np.ndarray) -> Slab:
    """Lower shelf whose outline passes through the leg centres (front_right: [3] at shelf height)."""
    lt, t = style["leg_thickness"], style["shelf_thickness"]
    a, b = float(front_right[0]), float(front_right[2])
    if style["top"] != "rectangular":
        a, b = a * math.sqrt(2.0), b * math.sqrt(2.0)  # the ellipse through the leg centres
    return Slab(
        centre=(0.0, style["shelf_height"], 0.0),
        half_x=a + lt / 2,
        half_z=b + lt / 2,
        half_height=t / 2,
        profile="rect" if style["top"] == "rectangular" else "ellipse",
        edge_radius=0.3 * t,
    )


def _four_legs(style: dict, parts: dict) -> None:
    lt, profile = style["leg_thickness"], style["leg_profile"]
    under = style["table_height"] - style["top_thickness"]
    top_y = under + min(0.01, style["top_thickness"] / 2)
    anchors = _leg_anchors(style, lt / 2 + style["leg_inset"])
    tops, bottoms = splayed_legs(anchors, top_y, style["leg_splay_deg"])
    taper = 0.55 if profile == "tapered" else 1.0
    parts["legs"] = [rod(b, t, lt, profile, taper=taper) for b, t in zip(bottoms, tops)]

    def on_leg(i: int, y: float) -> np.ndarray:
        return bottoms[i] + (tops[i] - bottoms[i]) * (y / top_y)

    bar = "square" if profile == "square" else "round"
    if style["apron"]:
        h = style["apron_height"]
        y = under - h / 2 + 0.002
        parts["apron"] = [
            Box.between(on_leg(i, y), on_leg(j, y), h, 0.022, hint=(0.0, 1.0, 0.0)) for i, j in _PAIRS["box"]
        ]
    if style["stretchers"]:
        y, layout = style["stretcher_height"], style["stretcher_layout"]
        bars = [rod(on_leg(i, y), on_leg(j, y), 0.55 * lt, bar) for i, j in _PAIRS[layout]]
        if layout == "H":
            bars.append(rod((on_leg(0, y) + on_leg(2, y)) / 2, (on_leg(1, y) + on_leg(3, y)) / 2, 0.55 * lt, bar))
        parts["stretchers"] = bars
    if style["shelf"]:
        # Splayed legs stand wider at the shelf than under the top.
        parts["shelf"] = [_shelf(style, on_leg(1, style["shelf_height"]))]


def _pedestal_foot(style: dict, x: float) -> list[Primitive]:
    """Star, disc or cross foot centred at (x, 0, 0)."""
    r, foot = style["foot_radius"], style["pedestal_foot"]
    if foot == "disc":
        return [Slab(centre=(x, 0.02, 0), half_x=r, half_z=r, half_height=0.02, profile="ellipse", edge_radius=0.008)]
    n = 4 if foot == "cross" else style["foot_spokes"]
    prims: list[Primitive] = []
    for i in range(n):
        angle = 2 * math.pi * i / n + (math.pi / 4 if foot == "star" else 0.0)
        tip = np.array([x + r * math.cos(angle), 0.025, r * math.sin(angle)])
        hub = (x, 0.05 if foot == "star" else 0.03, 0.0)
        if foot == "star":
            prims.append(Box.between(hub, tip, 0.05, 0.05, hint=(0.0, 1.0, 0.0), radius=0.01))
        else:
            prims.append(Box.between((x, 0.03, 0.0), (tip[0], 0.03, tip[2]), 0.06, 0.07, hint=(0.0, 1.0, 0.0)))
    return prims


def _pedestal(style: dict, parts: dict) -> None:
    under = style["table_height"] - style["top_thickness"]
    r = style["column_radius"]
    n = style["n_pedestals"]
    xs = [0.0] if n == 1 else [-style["top_length"] / 4, style["top_length"] / 4]
    bottom_r = 1.8 * r if style["column_profile"] == "flared" else r
    parts["column"], parts["base"] = [], []
    for x in xs:
        parts["column"].append(CappedCone(a=(x, 0.02, 0), b=(x, under + 0.005, 0), radius_a=bottom_r, radius_b=r))
        plate = min(0.2, 0.3 * style["top_width"])
        parts["column"].append(
            Slab(centre=(x, under - 0.01, 0), half_x=plate, half_z=plate, half_height=0.01, profile="ellipse")
        )
        parts["base"] += _pedestal_foot(style, x)
    if n == 2 and style["stretchers"]:
        y = style["stretcher_height"]
        parts["stretchers"] = [Box.between((xs[0], y, 0), (xs[1], y, 0), 0.08, 0.04, hint=(0.0, 1.0, 0.0))]


def _trestle(style: dict, parts: dict) -> None:
    under = style["table_height"] - style["top_thickness"]
    x_end = style["top_length"] / 2 - style["trestle_inset"]
    half_foot, w = style["foot_length"] / 2, style["member_width"]
    foot_h, cleat_h = 0.06, 0.04
    parts["base"], parts["legs"] = [], []
    for x in (-x_end, x_end):
        parts["base"].append(Box(centre=(x, foot_h / 2, 0), half=(w / 2, foot_h / 2, half_foot), radius=0.01))
        parts["base"].append(Box(centre=(x, under - cleat_h / 2, 0), half=(w / 2, cleat_h / 2, 0.9 * half_foot)))
        low, high = foot_h / 2, under - cleat_h / 2
        kind = style["trestle_upright"]
        if kind == "board":
            board = Box(centre=(x, (low + high) / 2, 0), half=(0.4 * w, (high - low) / 2, style["board_width"] / 2))
            parts["legs"].append(board)
        elif kind == "twin_posts":
            parts["legs"] += [Box.between((x, low, z), (x, high, z), w, w) for z in (-0.6 * half_foot, 0.6 * half_foot)]
        else:
            reach = 0.8 * half_foot
            parts["legs"] += [
                Box.between((x, low, -reach), (x, high, reach), 0.8 * w, 0.8 * w, hint=(1.0, 0.0, 0.0)),
                Box.between((x, low, reach), (x, high, -reach), 0.8 * w, 0.8 * w, hint=(1.0, 0.0, 0.0)),
            ]
    if style["stretchers"]:
        # X legs cross at mid height; a beam elsewhere would hang in the air between the diagonals.
        kind = style["trestle_upright"]
        y = (foot_h / 2 + under - cleat_h / 2) / 2 if kind == "x_legs" else style["stretcher_height"]
        zs = (-0.6 * half_foot, 0.6 * half_foot) if kind == "twin_posts" else (0.0,)
        parts["stretchers"] = [
            Box.between((-x_end, y, z), (x_end, y, z), 0.08, 0.035, hint=(0.0, 1.0, 0.0)) for z in zs
        ]


def build_table(style: dict) -> dict[str, list[Primitive]]:
    """Part name -> primitives (raw frame) for a table style from sample_table_style."""
    parts: dict[str, list[Primitive]] = {name: [] for name in PART_ORDER}
    parts["top"] = [_top(style)]
    builders = {"four_legs": _four_legs, "pedestal": _pedestal, "trestle": _trestle}
    if style["base"] not in builders:
        raise ValueError(f"unknown table base {style['base']!r}; expected one of {sorted(builders)}")
    builders[style["base"]](style, parts)
    return {name: prims for name, prims in parts.items() if prims}
