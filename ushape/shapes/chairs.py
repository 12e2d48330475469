"""A chair's primitives from its style (raw frame: metres, y up, front +Z, seat centred on x = z = 0)."""

from __future__ import annotations

import math

import numpy as np

from ushape.shapes.chair_backs import BackMount, build_back
from ushape.shapes.members import rod, splayed_legs
from ushape.shapes.primitives import Box, CappedCone, Capsule, Primitive, Slab, Torus

PART_ORDER = ("seat", "back", "arms", "legs", "apron", "stretchers", "column", "base", "footrest")
_CASTER_RADIUS = 0.025


def seat_half_width(style: dict, z: float) -> float:
    """Half width of the seat outline at depth z (metres)."""
    w, d, corner = style["seat_width"] / 2, style["seat_depth"] / 2, style["seat_corner"]
    if style["seat_shape"] == "round":
        return w * math.sqrt(max(0.0, 1.0 - (z / d) ** 2))
    over = abs(z) - (d - corner)
    return w if over <= 0 else w - corner + math.sqrt(max(0.0, corner**2 - over**2))


def _seat(style: dict) -> Slab:
    t = style["seat_thickness"]
    return Slab(
        centre=(0.0, style["seat_height"] - t / 2, 0.0),
        half_x=style["seat_width"] / 2,
        half_z=style["seat_depth"] / 2,
        half_height=t / 2,
        profile="ellipse" if style["seat_shape"] == "round" else "rect",
        corner_radius=style["seat_corner"],
        edge_radius=min(0.3 * t, 0.012),
    )


def _leg_anchors(style: dict, inset: float) -> np.ndarray:
    """[4,2] (x, z) of leg tops: front-left, front-right, back-left, back-right."""
    w, d = style["seat_width"] / 2 - inset, style["seat_depth"] / 2 - inset
    if style["seat_shape"] == "round":
        w, d = w / math.sqrt(2.0), d / math.sqrt(2.0)
    else:
        # Rounded corners cut the rectangle; pull legs in so they stay under the seat.
        cut = style["seat_corner"] * (1.0 - 1.0 / math.sqrt(2.0))
        w, d = w - cut, d - cut
    return np.array([[-w, d], [w, d], [-w, -d], [w, -d]])


def _stretcher_pairs(layout: str) -> list[tuple[int, int]]:
    return [(0, 1), (2, 3), (0, 2), (1, 3)] if layout == "box" else [(0, 2), (1, 3)]


def _four_legs(style: dict, parts: dict) -> BackMount:
    t, lt, profile = style["seat_thickness"], style["leg_thickness"], style["leg_profile"]
    yb = style["seat_height"] - t
    top_y = yb + min(0.01, t / 2)
    anchors = _leg_anchors(style, lt / 2 + 0.012)
    tops, bottoms = splayed_legs(anchors, top_y, style["leg_splay_deg"])
    taper = 0.6 if profile == "tapered" else 1.0
    parts["legs"] = [rod(b, tp, lt, profile, taper=taper) for b, tp in zip(bottoms, tops)]

    def on_leg(i: int, y: float) -> np.ndarray:
        return bottoms[i] + (tops[i] - bottoms[i]) * (y / top_y)

    bar = "square" if profile == "square" else "round"
    if style["stretchers"]:
        y = style["stretcher_height"]
        pairs = _stretcher_pairs(style["stretcher_layout"])
        bars = [rod(on_leg(i, y), on_leg(j, y), 0.6 * lt, bar) for i, j in pairs]
        if style["stretcher_layout"] == "H":
            left, right = (on_leg(0, y) + on_leg(2, y)) / 2, (on_leg(1, y) + on_leg(3, y)) / 2
            bars.append(rod(left, right, 0.6 * lt, bar))
        parts["stretchers"] = bars
    if style["apron"]:
        ah = style["apron_height"]
        y = yb - ah / 2 + 0.002
        parts["apron"] = [
            Box.between(on_leg(i, y), on_leg(j, y), ah, 0.02, hint=(0.0, 1.0, 0.0)) for i, j in _stretcher_pairs("box")
        ]
    post = "round" if profile == "tapered" else profile
    return BackMount(x=float(anchors[3, 0]), z=float(anchors[3, 1]), posts=post, post_thickness=0.9 * lt)


def _star_foot(style: dict) -> tuple[list[Primitive], float]:
    """Office-chair star: hub, spokes and caster balls. Returns (primitives, hub top height)."""
    rc = _CASTER_RADIUS
    hub_lo, hub_hi = 2 * rc - 0.005, 2 * rc + 0.05
    prims: list[Primitive] = [CappedCone(a=(0, hub_lo, 0), b=(0, hub_hi, 0), radius_a=0.045, radius_b=0.045)]
    n, length = style["star_spokes"], style["spoke_length"]
    for i in range(n):
        angle = math.pi / 2 + 2 * math.pi * i / n
        c, s = math.cos(angle), math.sin(angle)
        tip = np.array([length * c, 2 * rc + 0.01, length * s])
        prims.append(Box.between((0, (hub_lo + hub_hi) / 2, 0), tip, 0.035, 0.04, hint=(0.0, 1.0, 0.0)))
        prims.append(Capsule(a=(tip[0], rc, tip[2]), b=(tip[0], rc, tip[2]), radius=rc))
    return prims, hub_hi


def _pedestal(style: dict, parts: dict) -> BackMount:
    yb = style["seat_height"] - style["seat_thickness"]
    cr = style["column_radius"]
    if style["pedestal_foot"] == "star":
        parts["base"], hub_top = _star_foot(style)
        mid = hub_top + 0.45 * (yb - hub_top)
        parts["column"] = [
            CappedCone(a=(0, hub_top - 0.01, 0), b=(0, mid, 0), radius_a=1.5 * cr, radius_b=1.5 * cr),
            CappedCone(a=(0, mid - 0.01, 0), b=(0, yb + 0.005, 0), radius_a=cr, radius_b=cr),
        ]
    else:
        r, th = style["disc_radius"], 0.02
        disc = Slab(centre=(0, th / 2, 0), half_x=r, half_z=r, half_height=th / 2, profile="ellipse", edge_radius=0.006)
        parts["base"] = [disc]
        parts["column"] = [CappedCone(a=(0, th / 2, 0), b=(0, yb + 0.005, 0), radius_a=2.2 * cr, radius_b=cr)]
    plate = min(0.09, 0.35 * style["seat_width"])
    parts["column"].append(Box(centre=(0, yb - 0.012, 0), half=(plate, 0.0125, plate), radius=0.004))
    if style["footrest_ring"]:
        y, major = style["seat_height"] - 0.42, 0.17
        parts["footrest"] = [Torus(centre=(0, y, 0), major=major, minor=0.012)]
        for i in range(3):
            angle = 2 * math.pi * i / 3 + math.pi / 2
            end = (major * math.cos(angle), y, major * math.sin(angle))
            parts["footrest"].append(Capsule(a=(0, y, 0), b=end, radius=0.01))
    if style["back"] == "none":
        return BackMount(x=0.0, z=0.0, posts=None, post_thickness=0.0)
    half = style["seat_width"] / 2 * (1.0 if style["arms"] else style["back_width_frac"])
    behind_seat = -style["seat_depth"] / 2 - 0.015 - style["back_thickness"] / 2
    return BackMount(x=half, z=behind_seat, posts=None, post_thickness=0.0)


def _tube_frame(style: dict, parts: dict) -> BackMount:
    """Sled (closed side loops) or cantilever (open at the back, a floor crossbar) in bent tube."""
    r, d = style["tube_radius"], style["seat_depth"] / 2
    yb = style["seat_height"] - style["seat_thickness"]
    x = style["seat_width"] / 2 - r - 0.01
    z_att = d - max(style["seat_corner"], 0.02) - r
    y_rail = yb - 0.6 * r
    over = style["runner_overhang"]
    z_front = d + over if style["base"] == "sled" else d - 0.02 + over
    z_back = -d - over
    tubes: list[Primitive] = []
    for sx in (-x, x):
        front_floor, back_floor = (sx, r, z_front), (sx, r, z_back)
        front_top, rear_top = (sx, y_rail, z_att), (sx, y_rail, -z_att)
        tubes += [Capsule(a=front_floor, b=back_floor, radius=r), Capsule(a=front_floor, b=front_top, radius=r)]
        tubes.append(Capsule(a=front_top, b=rear_top, radius=r))
        if style["base"] == "sled":
            tubes.append(Capsule(a=back_floor, b=rear_top, radius=r))
    if style["base"] == "cantilever":
        tubes.append(Capsule(a=(-x, r, z_back), b=(x, r, z_back), radius=r))
    parts["base"] = tubes
    return BackMount(x=x, z=-z_att, posts="tube", post_thickness=2 * r)


def _arms(style: dict, mount: BackMount) -> list[Primitive]:
    h, t, d = style["seat_height"], style["seat_thickness"], style["seat_depth"] / 2
    aw, at = style["arm_width"], style["arm_thickness"]
    y = h + style["arm_height"]
    z_support = style["arm_support_z"] * 2 * d
    x = min(style["seat_width"] / 2 - 0.3 * aw, seat_half_width(style, z_support) - 0.01)
    z_rear = mount.z - style["arm_height"] * math.tan(math.radians(style["back_tilt_deg"]))
    z_front = d + 0.01
    tube = style["base"] in ("sled", "cantilever")
    prims: list[Primitive] = []
    for sx in (-x, x):
        rest_a, rest_b = (sx, y, z_rear), (sx, y, z_front)
        low, high = (sx, h - t / 2, z_support), (sx, y, z_support)
        if tube:
            r = style["tube_radius"]
            prims += [Capsule(a=rest_a, b=rest_b, radius=r), Capsule(a=low, b=high, radius=r)]
        else:
            prims.append(Box.between(rest_a, rest_b, aw, at, hint=(1.0, 0.0, 0.0), radius=0.3 * at))
            prims.append(Box.between(low, high, min(aw, 0.04), 0.03, hint=(1.0, 0.0, 0.0)))
    return prims


def build_chair(style: dict) -> dict[str, list[Primitive]]:
    """Part name -> primitives (raw frame) for a chair style from sample_chair_style."""
    parts: dict[str, list[Primitive]] = {name: [] for name in PART_ORDER}
    parts["seat"] = [_seat(style)]
    builders = {"four_legs": _four_legs, "pedestal": _pedestal, "sled": _tube_frame, "cantilever": _tube_frame}
    if style["base"] not in builders:
        raise ValueError(f"unknown chair base {style['base']!r}; expected one of {sorted(builders)}")
    mount = builders[style["base"]](style, parts)
    if style["back"] != "none":
        parts["back"] = build_back(style, mount)
    if style["arms"]:
        parts["arms"] = _arms(style, mount)
    return {name: prims for name, prims in parts.items() if prims}
