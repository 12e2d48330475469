"""Primitive SDFs against hand-computed distances, plus exactness properties on random points."""

import math

import numpy as np
import pytest

from ushape.shapes.planar import ellipse_sdf, rounded_rect_sdf
from ushape.shapes.primitives import Box, CappedCone, Capsule, Slab, Torus
from ushape.shapes.rigid import frame_along, rot_x, rot_y


def pts(*rows):
    return np.array(rows, dtype=np.float64)


def test_box_known_distances():
    box = Box(half=(1.0, 1.0, 1.0))
    got = box.sdf(pts([2, 0, 0], [0, 0, 0], [2, 2, 0], [0.5, 0, 0], [2, 2, 2]))
    np.testing.assert_allclose(got, [1.0, -1.0, math.sqrt(2), -0.5, math.sqrt(3)], atol=1e-12)


def test_rounded_box_keeps_faces_and_rounds_corners():
    box = Box(half=(1.0, 1.0, 1.0), radius=0.5)
    got = box.sdf(pts([2, 0, 0], [2, 2, 2]))
    np.testing.assert_allclose(got, [1.0, math.sqrt(3) * 1.5 - 0.5], atol=1e-12)


def test_rotated_and_translated_box():
    # rot_y(90 deg) takes local x to world -z: the long side (half 1) now runs along z.
    box = Box(centre=(5, 0, 0), rotation=rot_y(math.pi / 2), half=(1.0, 0.5, 0.2))
    got = box.sdf(pts([5, 0, 3], [8, 0, 0], [5, 0, 0]))
    np.testing.assert_allclose(got, [2.0, 2.8, -0.2], atol=1e-12)


def test_box_between_orients_width_along_hint():
    beam = Box.between((0, 0, 0), (0, 0, 2), width=0.2, depth=0.4, hint=(1, 0, 0))
    # local y runs along z (half 1), local x = world x (half 0.1), local z = x cross y = -y (half 0.2)
    got = beam.sdf(pts([1, 0, 1], [0, 1, 1], [0, 0, 3]))
    np.testing.assert_allclose(got, [0.9, 0.8, 1.0], atol=1e-12)


def test_cylinder_known_distances():
    cyl = CappedCone(a=(0, 0, 0), b=(0, 2, 0), radius_a=0.5, radius_b=0.5)
    got = cyl.sdf(pts([1, 1, 0], [0, 3, 0], [1, 3, 0], [0, 1, 0], [0, 1.9, 0]))
    np.testing.assert_allclose(got, [0.5, 1.0, math.hypot(0.5, 1.0), -0.5, -0.1], atol=1e-12)


def test_cone_known_distances():
    cone = CappedCone(a=(0, 0, 0), b=(0, 1, 0), radius_a=1.0, radius_b=0.5)
    # (r, y) = (2, 0.5): the slanted side's nearest point is its lower end (1, 0).
    got = cone.sdf(pts([0, 2, 0], [2, 0.5, 0], [0, -0.5, 0]))
    np.testing.assert_allclose(got, [1.0, math.hypot(1.0, 0.5), 0.5], atol=1e-12)


def test_capsule_and_sphere_known_distances():
    cap = Capsule(a=(0, 0, 0), b=(1, 0, 0), radius=0.25)
    got = cap.sdf(pts([0.5, 1, 0], [2, 0, 0], [-1, 1, 0], [0.5, 0, 0]))
    np.testing.assert_allclose(got, [0.75, 0.75, math.sqrt(2) - 0.25, -0.25], atol=1e-12)
    ball = Capsule(a=(1, 1, 1), b=(1, 1, 1), radius=0.5)
    np.testing.assert_allclose(ball.sdf(pts([1, 1, 3])), [1.5], atol=1e-12)


def test_torus_known_distances():
    ring = Torus(major=1.0, minor=0.25)
    got = ring.sdf(pts([0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]))
    np.testing.assert_allclose(got, [0.75, -0.25, 0.75, math.sqrt(2) - 0.25], atol=1e-12)


def test_slab_known_distances():
    oval = Slab(half_x=1.0, half_z=0.5, half_height=0.1, profile="ellipse")
    got = oval.sdf(pts([0, 0, 0.8], [2, 0, 0], [0, 0.3, 0], [0, 0, 0]))
    np.testing.assert_allclose(got, [0.3, 1.0, 0.2, -0.1], atol=1e-9)
    plate = Slab(half_x=1.0, half_z=1.0, half_height=0.1, corner_radius=0.5)
    got = plate.sdf(pts([2, 0, 2], [2, 0, 0]))
    np.testing.assert_allclose(got, [math.sqrt(2) * 1.5 - 0.5, 1.0], atol=1e-12)


@pytest.mark.parametrize("a,b", [(1.0, 1.0), (1.0, 0.5), (1.0, 0.1), (0.3, 1.0)])
def test_ellipse_sdf_matches_brute_force(a, b):
    rng = np.random.default_rng(1)
    p = rng.uniform(-1.5, 1.5, (300, 2)) * max(a, b)
    # Brute force: nearest of 20k curve samples, then 2k finer samples around it.
    coarse = np.linspace(0.0, 2.0 * np.pi, 20_000, endpoint=False)
    d2 = (p[:, :1] - a * np.cos(coarse)) ** 2 + (p[:, 1:] - b * np.sin(coarse)) ** 2
    fine = coarse[np.argmin(d2, 1)][:, None] + np.linspace(-1e-3, 1e-3, 2001)
    brute = np.hypot(p[:, :1] - a * np.cos(fine), p[:, 1:] - b * np.sin(fine)).min(1)
    got = ellipse_sdf(p[:, 0], p[:, 1], a, b)
    np.testing.assert_allclose(np.abs(got), brute, atol=1e-7)
    inside = (p[:, 0] / a) ** 2 + (p[:, 1] / b) ** 2 < 1
    assert np.all((got < 0) == inside)
    # The centre of a circle has a well-defined distance (no 0/0).
    assert ellipse_sdf(np.zeros(1), np.zeros(1), 0.4, 0.4)[0] == pytest.approx(-0.4)


def test_rounded_rect_sdf_known_values():
    got = rounded_rect_sdf(np.array([3.0, 0.0, 2.0]), np.array([0.0, 0.0, 1.0]), 2.0, 1.0, 0.5)
    np.testing.assert_allclose(got, [1.0, -1.0, (math.sqrt(2) - 1) * 0.5], atol=1e-12)


PRIMITIVES = [
    Box(centre=(0.1, 0.2, 0.3), rotation=frame_along((1, 2, 3)), half=(0.3, 0.2, 0.1), radius=0.05),
    Slab(rotation=rot_x(0.3), half_x=0.5, half_z=0.2, half_height=0.05, profile="ellipse", edge_radius=0.02),
    Slab(centre=(0, 0.1, 0), half_x=0.5, half_z=0.3, half_height=0.04, corner_radius=0.1, edge_radius=0.01),
    CappedCone(a=(0, 0, 0), b=(0.2, 0.5, 0.1), radius_a=0.2, radius_b=0.05),
    Capsule(a=(0, 0, 0), b=(0.3, 0.1, -0.2), radius=0.07),
    Torus(centre=(0, 0.2, 0), rotation=rot_x(0.5), major=0.4, minor=0.05),
]


@pytest.mark.parametrize("prim", PRIMITIVES, ids=lambda p: type(p).__name__)
def test_exact_sdf_projects_onto_its_zero_set(prim):
    """An exact SDF has unit gradient and p - sdf(p) * grad lands on the surface."""
    rng = np.random.default_rng(0)
    p = rng.uniform(-0.8, 0.8, (400, 3))
    d = prim.sdf(p)
    eps = 1e-6
    grad = np.stack([(prim.sdf(p + eps * e) - prim.sdf(p - eps * e)) / (2 * eps) for e in np.eye(3)], 1)
    outside = d > 1e-3  # exact outside; inside a union-free primitive too, but skip medial axes
    np.testing.assert_allclose(np.linalg.norm(grad[outside], axis=1), 1.0, atol=1e-4)
    landed = prim.sdf(p[outside] - d[outside, None] * grad[outside])
    assert np.abs(landed).max() < 1e-5


@pytest.mark.parametrize("prim", PRIMITIVES, ids=lambda p: type(p).__name__)
def test_aabb_and_max_distance_bound_the_surface(prim):
    rng = np.random.default_rng(2)
    lo, hi = prim.aabb()
    p = rng.uniform(lo - 0.05, hi + 0.05, (100_000, 3))
    inside = p[prim.sdf(p) <= 0]
    assert np.all(inside >= lo - 1e-12) and np.all(inside <= hi + 1e-12)
    # Dense samples nearly reach the box and the farthest distance, never beyond.
    assert np.all(inside.min(0) - lo < 0.03) and np.all(hi - inside.max(0) < 0.03)
    centre = np.array([0.05, -0.1, 0.2])
    far = np.linalg.norm(inside - centre, axis=1).max()
    assert far <= prim.max_distance(centre) + 1e-9
    assert far > prim.max_distance(centre) - 0.03


def test_max_distance_closed_forms():
    cyl = CappedCone(a=(0, -1, 0), b=(0, 1, 0), radius_a=0.5, radius_b=0.5)
    assert cyl.max_distance(np.zeros(3)) == pytest.approx(math.hypot(1.0, 0.5))
    assert Torus(major=1.0, minor=0.25).max_distance(np.zeros(3)) == pytest.approx(1.25)
    rounded = Box(half=(1, 2, 2), radius=0.5)  # inner corners at (0.5, 1.5, 1.5)
    assert rounded.max_distance(np.zeros(3)) == pytest.approx(math.sqrt(0.25 + 2.25 + 2.25) + 0.5)


def test_thickened_raises_only_thin_dimensions():
    box = Box(half=(1.0, 0.01, 0.5)).thickened(0.1)
    np.testing.assert_allclose(box.half, [1.0, 0.05, 0.5])
    disc = CappedCone(a=(0, 0, 0), b=(0, 0.02, 0), radius_a=1.0, radius_b=1.0).thickened(0.1)
    assert np.linalg.norm(disc.b - disc.a) == pytest.approx(0.1)
    assert Capsule(radius=0.01).thickened(0.1).radius == pytest.approx(0.05)
    assert Slab(half_height=0.01).thickened(0.1).half_height == pytest.approx(0.05)


def test_bad_parameters_raise_clear_errors():
    with pytest.raises(ValueError, match="half > 0"):
        Box(half=(1.0, -1.0, 1.0))
    with pytest.raises(ValueError, match="profile"):
        Slab(profile="hexagon")
    with pytest.raises(ValueError, match="orthonormal"):
        Box(rotation=np.ones((3, 3)))
    with pytest.raises(ValueError, match="distinct"):
        CappedCone(a=(0, 0, 0), b=(0, 0, 0))
    with pytest.raises(ValueError, match="hint"):
        frame_along((1, 0, 0), hint=(2, 0, 0))
