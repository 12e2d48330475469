"""Sampling a chair's style: structure (base, back, arms, seat shape) and proportions in metres.

Every key the builder reads is drawn here, so `build_chair(style)` is a pure function of the
dictionary and the dictionary alone describes the chair (the keys are listed in ushape.shapes).
"""

from __future__ import annotations

import numpy as np

from ushape.shapes.choices import choose
from ushape.shapes.palettes import sample_palette

CHAIR_BASES = ("four_legs", "pedestal", "sled", "cantilever")
CHAIR_BACKS = ("solid", "slatted", "open_frame", "none")
SEAT_SHAPES = ("rectangular", "rounded", "round")
LEG_PROFILES = ("square", "round", "tapered")
BACK_PANEL_SHAPES = ("rect", "rounded", "oval")


def _structure(rng: np.random.Generator) -> dict:
    """Base, back, arms and seat shape: the discrete choices that make chairs look different."""
    back = choose(rng, ("none", "solid", "slatted", "open_frame"), p=[0.16, 0.28, 0.28, 0.28])
    if back == "none":
        base = choose(rng, ("four_legs", "pedestal"), p=[0.6, 0.4])
    else:
        base = choose(rng, CHAIR_BASES, p=[0.4, 0.26, 0.17, 0.17])
    # Bent-tube frames attach along straight seat edges, so they take no round seat.
    seat_options = ("rectangular", "rounded") if base in ("sled", "cantilever") else SEAT_SHAPES
    seat_p = None if base in ("sled", "cantilever") else ([0.2, 0.3, 0.5] if back == "none" else [0.4, 0.35, 0.25])
    return {
        "base": base,
        "back": back,
        "arms": bool(back != "none" and rng.random() < 0.35),
        "seat_shape": choose(rng, seat_options, p=seat_p),
        "bar_height": bool(back == "none" and rng.random() < 0.5),
    }


def _seat(rng: np.random.Generator, s: dict) -> dict:
    stool = s["back"] == "none"
    width = rng.uniform(0.30, 0.42) if stool else rng.uniform(0.38, 0.52) + (0.05 if s["arms"] else 0.0)
    depth = width * rng.uniform(0.92, 1.0) if s["seat_shape"] == "round" else rng.uniform(0.36, 0.50)
    if s["seat_shape"] == "rectangular":
        corner = rng.uniform(0.004, 0.02)
    elif s["seat_shape"] == "rounded":
        corner = rng.uniform(0.06, 0.4) * min(width, depth)
    else:
        corner = 0.0
    return {
        "seat_height": rng.uniform(0.62, 0.80) if s["bar_height"] else rng.uniform(0.40, 0.50),
        "seat_width": width,
        "seat_depth": depth,
        "seat_thickness": rng.uniform(0.02, 0.08),
        "seat_corner": corner,
    }


def _back(rng: np.random.Generator, s: dict) -> dict:
    if s["back"] == "none":
        return {}
    horizontal = rng.random() < 0.35
    return {
        "back_height": rng.uniform(0.30, 0.55),
        "back_tilt_deg": rng.uniform(0.0, 18.0),
        "back_thickness": rng.uniform(0.02, 0.05),
        "back_gap": rng.uniform(0.0, 0.15),
        "back_width_frac": rng.uniform(0.75, 1.0),
        "back_panel_shape": choose(rng, BACK_PANEL_SHAPES),
        "rail_height": rng.uniform(0.035, 0.10),
        "slat_direction": "horizontal" if horizontal else "vertical",
        "n_slats": int(rng.integers(2, 5) if horizontal else rng.integers(3, 8)),
        "slat_width": rng.uniform(0.02, 0.05),
    }


def _legs(rng: np.random.Generator, s: dict) -> dict:
    profile = choose(rng, LEG_PROFILES)
    out = {
        "leg_profile": profile,
        "leg_thickness": rng.uniform(0.025, 0.045),
        "leg_splay_deg": 0.0 if profile == "square" else rng.uniform(0.0, 6.0),
        "stretchers": bool(rng.random() < (0.8 if s["bar_height"] else 0.45)),
        "apron": bool(s["seat_shape"] != "round" and rng.random() < 0.4),
    }
    if out["stretchers"]:
        out["stretcher_layout"] = choose(rng, ("box", "H"))
        out["stretcher_height"] = rng.uniform(0.22, 0.32) if s["bar_height"] else rng.uniform(0.10, 0.22)
    if out["apron"]:
        out["apron_height"] = rng.uniform(0.04, 0.08)
    return out


def _pedestal(rng: np.random.Generator, s: dict) -> dict:
    out = {
        "pedestal_foot": choose(rng, ("star", "disc"), p=[0.7, 0.3]),
        "column_radius": rng.uniform(0.02, 0.035),
        "footrest_ring": bool(s["bar_height"]),
    }
    if out["pedestal_foot"] == "star":
        out["star_spokes"] = int(rng.integers(4, 6))
        out["spoke_length"] = rng.uniform(0.24, 0.32)
    else:
        out["disc_radius"] = rng.uniform(0.18, 0.26)
    return out


def _arms(rng: np.random.Generator) -> dict:
    return {
        "arm_height": rng.uniform(0.18, 0.26),
        "arm_width": rng.uniform(0.035, 0.07),
        "arm_thickness": rng.uniform(0.02, 0.035),
        "arm_support_z": rng.uniform(0.0, 0.2),
    }


def _support(rng: np.random.Generator, s: dict) -> dict:
    """Legs, pedestal or tubes, and the arms: what holds the seat up. Only the keys that apply."""
    if s["base"] == "four_legs":
        out = _legs(rng, s)
    elif s["base"] == "pedestal":
        out = _pedestal(rng, s)
    else:
        out = {"tube_radius": rng.uniform(0.010, 0.016), "runner_overhang": rng.uniform(0.0, 0.06)}
    if s["arms"]:
        out.update(_arms(rng))
    return out


def sample_chair_style(rng: np.random.Generator) -> dict:
    """All choices and proportions of one chair (plain Python values, metres and degrees)."""
    style = _structure(rng)
    style.update(_seat(rng, style))
    style.update(_back(rng, style))
    style.update(_support(rng, style))
    style["palette"], style["colours"] = sample_palette(rng)
    return {k: (float(v) if isinstance(v, np.floating) else v) for k, v in style.items()}
