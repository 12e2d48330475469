"""The public generator: ids, determinism, style coverage, frames and parts (no meshes, fast)."""

import collections

import numpy as np
import pytest

from ushape.shapes import CATEGORIES, MIN_THICKNESS, generate_shape, sample_style
from ushape.shapes.primitives import Box, CappedCone, Capsule, Slab, Torus

N_STYLES = 200


def test_shape_id_and_category():
    shape = generate_shape("chairs", 123)
    assert shape.shape_id == "chairs_000123" and shape.category == "chairs"
    assert generate_shape("tables", 7).shape_id == "tables_000007"


def test_unknown_category_and_bad_seed_errors():
    with pytest.raises(ValueError, match=r"valid categories are \['chairs', 'tables'\]"):
        generate_shape("sofas", 0)
    with pytest.raises(ValueError, match="non-negative integer"):
        generate_shape("chairs", -1)
    with pytest.raises(ValueError, match="non-negative integer"):
        generate_shape("chairs", 1.5)


@pytest.mark.parametrize("category", CATEGORIES)
def test_same_seed_same_shape_different_seed_different_shape(category):
    points = np.random.default_rng(0).uniform(-1, 1, (2000, 3))
    a, b = generate_shape(category, 42), generate_shape(category, 42)
    assert a.style == b.style
    np.testing.assert_array_equal(a.sdf(points), b.sdf(points))
    values = [generate_shape(category, s).sdf(points) for s in range(43, 53)]
    for v in values:
        assert np.abs(v - a.sdf(points)).max() > 1e-3


def test_categories_draw_independent_streams():
    assert sample_style("chairs", 5)["colours"] != sample_style("tables", 5)["colours"]


def _counts(category, key):
    return collections.Counter(sample_style(category, s).get(key) for s in range(N_STYLES))


# (category, key, every value that must appear, minimum count of each among N_STYLES seeds)
COVERAGE = [
    ("chairs", "base", ("four_legs", "pedestal", "sled", "cantilever"), 20),
    ("chairs", "back", ("solid", "slatted", "open_frame", "none"), 15),
    ("chairs", "arms", (True, False), 30),
    ("chairs", "seat_shape", ("rectangular", "rounded", "round"), 20),
    ("chairs", "bar_height", (True, False), 5),
    ("chairs", "leg_profile", ("square", "round", "tapered"), 8),
    ("chairs", "pedestal_foot", ("star", "disc"), 10),
    ("chairs", "slat_direction", ("vertical", "horizontal"), 30),
    ("chairs", "back_panel_shape", ("rect", "rounded", "oval"), 30),
    ("chairs", "stretchers", (True, False), 15),
    ("chairs", "stretcher_layout", ("box", "H"), 8),
    ("tables", "size_class", ("coffee", "dining", "bar", "side"), 25),
    ("tables", "base", ("four_legs", "pedestal", "trestle"), 20),
    ("tables", "top", ("rectangular", "round", "oval"), 30),
    ("tables", "stretchers", (True, False), 30),
    ("tables", "shelf", (True, False), 6),
    ("tables", "apron", (True, False), 25),
    ("tables", "stretcher_layout", ("box", "H", "X"), 3),
    ("tables", "trestle_upright", ("board", "twin_posts", "x_legs"), 5),
    ("tables", "pedestal_foot", ("star", "disc", "cross"), 10),
    ("tables", "n_pedestals", (1, 2), 5),
]


@pytest.mark.parametrize("category,key,values,minimum", COVERAGE, ids=lambda v: str(v)[:20])
def test_every_style_appears_often_enough(category, key, values, minimum):
    counts = _counts(category, key)
    for value in values:
        assert counts[value] >= minimum, f"{category}.{key}={value!r}: {counts[value]} of {N_STYLES}"


def test_trestles_have_no_round_tops():
    tops = [sample_style("tables", s)["top"] for s in range(N_STYLES) if sample_style("tables", s)["base"] == "trestle"]
    assert tops and "round" not in tops


def _min_size(prim):
    if isinstance(prim, Box):
        return 2 * prim.half.min()
    if isinstance(prim, Slab):
        return 2 * min(prim.half_x, prim.half_z, prim.half_height)
    if isinstance(prim, CappedCone):
        return min(2 * prim.radius_a, 2 * prim.radius_b, np.linalg.norm(prim.b - prim.a))
    if isinstance(prim, Capsule):
        return 2 * prim.radius
    assert isinstance(prim, Torus)
    return 2 * prim.minor


@pytest.mark.parametrize("category", CATEGORIES)
def test_parts_colours_and_thickness_over_many_shapes(category):
    for seed in range(40):
        shape = generate_shape(category, seed)
        names = shape.part_names
        assert len(names) == len(set(names)) == len(shape.parts) >= 2
        colours = shape.part_colours()
        assert colours.shape == (len(names), 3) and colours.min() >= 0 and colours.max() <= 1
        thinnest = min(_min_size(p) for part in shape.parts for p in part.primitives) / shape.scale
        assert thinnest >= MIN_THICKNESS * (1 - 1e-3), (shape.shape_id, thinnest)
        lo, hi = shape.bounds()
        # Standing on the floor (raw y = 0; splayed round feet dip a few mm), centred.
        assert shape.centre[1] + shape.scale * lo[1] == pytest.approx(0.0, abs=0.005)
        np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-9)


def test_chairs_face_plus_z_and_stand_up_along_y():
    """Backs are behind the seat (-Z) and reach above it (+Y)."""
    checked = 0
    for seed in range(30):
        shape = generate_shape("chairs", seed)
        if "back" not in shape.part_names:
            continue
        seat = shape.parts[shape.part_names.index("seat")].primitives[0]
        back = shape.parts[shape.part_names.index("back")].primitives
        back_lo, back_hi = np.min([p.aabb()[0] for p in back], 0), np.max([p.aabb()[1] for p in back], 0)
        assert back_lo[2] < seat.centre[2] and back_hi[1] > seat.centre[1] + 0.2
        checked += 1
    assert checked > 10


def test_part_index_and_part_sdf_agree_with_sdf():
    shape = generate_shape("tables", 3)
    points = np.random.default_rng(1).uniform(-1, 1, (3000, 3))
    per_part = shape.part_sdf(points)
    np.testing.assert_allclose(per_part.min(0), shape.sdf(points), atol=1e-12)
    np.testing.assert_array_equal(shape.part_index(points), per_part.argmin(0))  # part_index is this argmin
    # A point just under the middle of the top belongs to the top.
    lo, hi = shape.bounds()
    probe = np.array([[0.0, hi[1] - 0.01, 0.0]])
    assert shape.part_names[shape.part_index(probe)[0]] == "top"
    assert shape.sdf(probe)[0] < 0


def test_sdf_rejects_bad_point_arrays():
    with pytest.raises(ValueError, match=r"\[N, 3\]"):
        generate_shape("chairs", 0).sdf(np.zeros((4, 2)))
