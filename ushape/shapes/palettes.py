"""Per-shape colour palettes: each part takes the colour of its role (surface, frame or accent)."""

from __future__ import annotations

import numpy as np

WOODS = {
    "oak": (0.76, 0.60, 0.42),
    "beech": (0.85, 0.70, 0.50),
    "pine": (0.88, 0.75, 0.52),
    "teak": (0.60, 0.42, 0.25),
    "cherry": (0.55, 0.30, 0.18),
    "walnut": (0.36, 0.24, 0.15),
    "mahogany": (0.42, 0.18, 0.12),
    "ebony": (0.15, 0.11, 0.09),
}
METALS = {
    "chrome": (0.76, 0.77, 0.79),
    "steel": (0.55, 0.56, 0.58),
    "gunmetal": (0.30, 0.31, 0.33),
    "black": (0.08, 0.08, 0.09),
    "brass": (0.72, 0.58, 0.30),
}
PAINTS = {
    "red": (0.75, 0.15, 0.12),
    "blue": (0.15, 0.30, 0.60),
    "green": (0.25, 0.50, 0.30),
    "yellow": (0.90, 0.75, 0.20),
    "teal": (0.10, 0.50, 0.50),
    "orange": (0.90, 0.45, 0.10),
    "grey": (0.50, 0.50, 0.50),
    "white": (0.92, 0.92, 0.90),
    "black": (0.10, 0.10, 0.10),
    "pink": (0.90, 0.70, 0.70),
    "mint": (0.65, 0.85, 0.75),
}
FABRICS = {
    "charcoal": (0.25, 0.25, 0.27),
    "beige": (0.78, 0.72, 0.60),
    "navy": (0.15, 0.18, 0.32),
    "burgundy": (0.45, 0.10, 0.15),
    "olive": (0.45, 0.45, 0.25),
    "mustard": (0.80, 0.60, 0.15),
    "light_grey": (0.70, 0.70, 0.70),
}
PALETTES = ("wood", "two_tone_wood", "metal_frame", "painted", "upholstered", "white_modern")

# Which palette role colours each part name (part names are listed in ushape.shapes).
PART_ROLES = {
    "seat": "surface",
    "back": "accent",
    "top": "surface",
    "shelf": "surface",
    "apron": "surface",
    "arms": "accent",
    "legs": "frame",
    "base": "frame",
    "column": "frame",
    "stretchers": "frame",
    "footrest": "frame",
}


def _pick(rng: np.random.Generator, table: dict) -> tuple[float, float, float]:
    return table[list(table)[rng.integers(len(table))]]


def _jitter(rng: np.random.Generator, rgb) -> list[float]:
    """Vary a base colour by a few percent per channel so two oak chairs are not identical."""
    return [float(c) for c in np.clip(np.asarray(rgb) * rng.uniform(0.92, 1.08, 3), 0.0, 1.0)]


def sample_palette(rng: np.random.Generator) -> tuple[str, dict[str, list[float]]]:
    """(palette name, {"surface", "frame", "accent"} -> RGB in [0, 1]) drawn from `rng`."""
    name = PALETTES[rng.integers(len(PALETTES))]
    if name == "wood":
        wood = _pick(rng, WOODS)
        roles = {"surface": wood, "frame": wood, "accent": wood}
    elif name == "two_tone_wood":
        light, dark = sorted([_pick(rng, WOODS), _pick(rng, WOODS)], key=sum, reverse=True)
        roles = {"surface": light, "frame": dark, "accent": light}
    elif name == "metal_frame":
        surface = _pick(rng, WOODS) if rng.random() < 0.5 else _pick(rng, PAINTS)
        roles = {"surface": surface, "frame": _pick(rng, METALS), "accent": surface}
    elif name == "painted":
        paint = _pick(rng, PAINTS)
        roles = {"surface": paint, "frame": paint, "accent": paint}
    elif name == "upholstered":
        fabric = _pick(rng, FABRICS)
        frame = _pick(rng, WOODS) if rng.random() < 0.5 else _pick(rng, METALS)
        roles = {"surface": fabric, "frame": frame, "accent": fabric}
    else:
        white = PAINTS["white"]
        frame = _pick(rng, {"black": METALS["black"], "chrome": METALS["chrome"], **WOODS})
        roles = {"surface": white, "frame": frame, "accent": white}
    return name, {role: _jitter(rng, rgb) for role, rgb in roles.items()}


def part_colours(roles: dict[str, list[float]], part_names) -> dict[str, list[float]]:
    """Colour of each named part from its role; unknown part names raise a ValueError."""
    unknown = [n for n in part_names if n not in PART_ROLES]
    if unknown:
        raise ValueError(f"no palette role for parts {unknown}; add them to PART_ROLES")
    return {n: roles[PART_ROLES[n]] for n in part_names}
