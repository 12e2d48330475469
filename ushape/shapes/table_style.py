"""Sampling a table's style: size class, top shape, base and its options, in metres.

Every key the builder reads is drawn here, so `build_table(style)` is a pure function of the
dictionary (the keys are listed in ushape.shapes).
"""

from __future__ import annotations

import numpy as np

from ushape.shapes.chair_style import LEG_PROFILES
from ushape.shapes.choices import choose
from ushape.shapes.palettes import sample_palette

TABLE_BASES = ("four_legs", "pedestal", "trestle")
TABLE_TOPS = ("rectangular", "round", "oval")
TABLE_SIZES = ("coffee", "dining", "bar", "side")

# size class -> (height, length, width as a fraction of length, round-top diameter, leg thickness),
# ranges in metres.
_SIZES = {
    "coffee": ((0.38, 0.48), (0.80, 1.30), (0.45, 0.70), (0.60, 1.00), (0.03, 0.06)),
    "dining": ((0.72, 0.78), (1.20, 2.00), (0.45, 0.70), (0.90, 1.30), (0.04, 0.08)),
    "bar": ((0.95, 1.08), (0.60, 1.20), (0.55, 0.90), (0.60, 0.80), (0.035, 0.06)),
    "side": ((0.50, 0.65), (0.40, 0.60), (0.75, 1.00), (0.40, 0.60), (0.025, 0.045)),
}


def _top(rng: np.random.Generator, size: str, base: str) -> dict:
    shape = choose(rng, ("rectangular", "oval") if base == "trestle" else TABLE_TOPS)
    height, length, ratio, diameter, _ = _SIZES[size]
    if shape == "round":
        top_length = top_width = rng.uniform(*diameter)
    else:
        top_length = rng.uniform(*length)
        top_width = top_length * rng.uniform(*ratio)
    corner = rng.uniform(0.0, 0.12) * min(top_length, top_width) if shape == "rectangular" else 0.0
    return {
        "top": shape,
        "table_height": rng.uniform(*height),
        "top_length": top_length,
        "top_width": top_width,
        "top_thickness": rng.uniform(0.02, 0.05),
        "top_corner": corner,
    }


def _four_legs(rng: np.random.Generator, s: dict) -> dict:
    profile = choose(rng, LEG_PROFILES)
    out = {
        "leg_profile": profile,
        "leg_thickness": rng.uniform(*_SIZES[s["size_class"]][4]),
        "leg_splay_deg": 0.0 if profile == "square" else rng.uniform(0.0, 7.0),
        "leg_inset": rng.uniform(0.02, 0.10),
        "apron": bool(rng.random() < 0.5),
        "shelf": bool(s["size_class"] in ("coffee", "side") and rng.random() < 0.45),
    }
    out["stretchers"] = bool(not out["shelf"] and rng.random() < 0.4)
    if out["apron"]:
        out["apron_height"] = rng.uniform(0.05, 0.12)
    if out["shelf"]:
        out["shelf_height"] = rng.uniform(0.08, 0.25) * s["table_height"]
        out["shelf_thickness"] = rng.uniform(0.015, 0.03)
    if out["stretchers"]:
        out["stretcher_layout"] = choose(rng, ("box", "H", "X"))
        out["stretcher_height"] = rng.uniform(0.1, 0.3) * s["table_height"]
    return out


def _pedestal(rng: np.random.Generator, s: dict) -> dict:
    double = bool(s["top"] != "round" and s["top_length"] > 1.3)
    return {
        "n_pedestals": 2 if double else 1,
        "column_radius": min(rng.uniform(0.035, 0.08), 0.1 * s["top_width"]),
        "column_profile": choose(rng, ("cylinder", "flared")),
        "pedestal_foot": choose(rng, ("star", "disc", "cross")),
        "foot_spokes": int(rng.integers(3, 5)),
        "foot_radius": rng.uniform(0.30, 0.45) * min(s["top_width"], 1.0),
        "stretchers": bool(double and rng.random() < 0.6),
        "stretcher_height": rng.uniform(0.1, 0.3) * s["table_height"],
    }


def _trestle(rng: np.random.Generator, s: dict) -> dict:
    return {
        "trestle_upright": choose(rng, ("board", "twin_posts", "x_legs")),
        "trestle_inset": rng.uniform(0.08, 0.25) * s["top_length"] / 2,
        "foot_length": rng.uniform(0.7, 0.9) * s["top_width"],
        "member_width": rng.uniform(0.05, 0.09),
        "board_width": rng.uniform(0.4, 0.8) * s["top_width"] * 0.8,
        "stretchers": bool(rng.random() < 0.7),
        "stretcher_height": rng.uniform(0.15, 0.45) * s["table_height"],
    }


def sample_table_style(rng: np.random.Generator) -> dict:
    """All choices and proportions of one table (plain Python values, metres and degrees)."""
    size = choose(rng, TABLE_SIZES, p=[0.25, 0.35, 0.15, 0.25])
    base = choose(rng, TABLE_BASES, p=[0.5, 0.3, 0.2])
    style = {"size_class": size, "base": base}
    style.update(_top(rng, size, base))
    builder = {"four_legs": _four_legs, "pedestal": _pedestal, "trestle": _trestle}[base]
    style.update(builder(rng, style))
    style["palette"], style["colours"] = sample_palette(rng)
    return {k: (float(v) if isinstance(v, np.floating) else v) for k, v in style.items()}
