"""One chair or table per (category, seed): sample a style, build its parts, normalise."""

from __future__ import annotations

import numpy as np

from ushape.shapes.chair_style import sample_chair_style
from ushape.shapes.chairs import build_chair
from ushape.shapes.palettes import part_colours
from ushape.shapes.shape import Shape, assemble_shape
from ushape.shapes.table_style import sample_table_style
from ushape.shapes.tables import build_table

CATEGORIES = ("chairs", "tables")
_GENERATORS = {"chairs": (sample_chair_style, build_chair), "tables": (sample_table_style, build_table)}


def _check(category: str, seed: int) -> None:
    if category not in CATEGORIES:
        raise ValueError(f"unknown shape category {category!r}; valid categories are {list(CATEGORIES)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")


def sample_style(category: str, seed: int) -> dict:
    """The style dictionary generate_shape(category, seed) builds, without building it (fast)."""
    _check(category, seed)
    # The category index salts the stream, so chairs_000007 and tables_000007 are unrelated draws.
    rng = np.random.default_rng([int(seed), CATEGORIES.index(category)])
    return _GENERATORS[category][0](rng)


def generate_shape(category: str, seed: int) -> Shape:
    """The shape `category`_`seed`: same arguments, same shape, on any machine."""
    style = sample_style(category, seed)
    parts = _GENERATORS[category][1](style)
    return assemble_shape(category, int(seed), style, parts, part_colours(style["colours"], parts))
