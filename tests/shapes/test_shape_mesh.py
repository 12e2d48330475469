"""Meshes of generated shapes agree with their analytic SDF (moderate resolution, a few shapes)."""

import numpy as np
import pytest

from ushape.shapes import SPHERE_BUFFER, generate_shape
from ushape.shapes.meshing import grid_spacing

RESOLUTION = 128
# A spread of structures: slatted armchair, cantilever, stool, office chair; pedestal, trestle, oval.
CASES = [("chairs", 0), ("chairs", 1), ("chairs", 3), ("chairs", 4), ("tables", 1), ("tables", 2), ("tables", 3)]


@pytest.fixture(scope="module", params=CASES, ids=lambda c: f"{c[0]}_{c[1]}")
def shape_and_mesh(request):
    shape = generate_shape(*request.param)
    mesh = shape.mesh(RESOLUTION)
    return shape, mesh, grid_spacing(*shape.bounds(), RESOLUTION)


def test_mesh_is_one_watertight_outward_piece(shape_and_mesh):
    _, mesh, _ = shape_and_mesh
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0
    assert len(mesh.split(only_watertight=False)) == 1  # no floating parts


def test_sdf_vanishes_on_mesh_vertices(shape_and_mesh):
    shape, mesh, h = shape_and_mesh
    assert np.abs(shape.sdf(mesh.vertices)).max() < 0.5 * h


def test_mesh_inside_agrees_with_sdf_sign(shape_and_mesh):
    shape, mesh, h = shape_and_mesh
    lo, hi = shape.bounds()
    rng = np.random.default_rng(0)
    # Uniform points see the whole box; points pushed off the surface probe thin parts from both sides.
    on_surface, faces = mesh.sample(2000, return_index=True, seed=0)
    offset = mesh.face_normals[faces] * rng.choice([-1.5, 1.5], size=(2000, 1)) * h
    points = np.concatenate([rng.uniform(lo - 0.05, hi + 0.05, (4000, 3)), on_surface + offset])
    sdf = shape.sdf(points)
    clear = np.abs(sdf) > h
    inside = mesh.contains(points[clear])
    assert (sdf[clear] < 0).sum() > 100  # the test sees both sides
    assert np.array_equal(inside, sdf[clear] < 0)


def test_mesh_fills_the_buffered_unit_sphere(shape_and_mesh):
    _, mesh, h = shape_and_mesh
    radius = np.linalg.norm(mesh.vertices, axis=1).max()
    assert radius <= 1 / SPHERE_BUFFER + 1e-9
    assert radius > 1 / SPHERE_BUFFER - h


def test_mesh_is_cached_and_returned_as_a_copy():
    shape = generate_shape("tables", 5)
    first = shape.mesh(48)
    first.apply_translation([1.0, 0.0, 0.0])
    second = shape.mesh(48)
    assert np.abs(second.vertices).max() < 1.0
    assert shape._meshes[48] is not second


@pytest.mark.parametrize("category", ["chairs", "tables"])
def test_no_floating_parts_over_many_seeds(category):
    """Every part touches the rest: the coarse mesh is one watertight piece (seeds 100..119)."""
    for seed in range(100, 120):
        mesh = generate_shape(category, seed).mesh(96)
        assert mesh.is_watertight, f"{category} {seed}"
        assert len(mesh.split(only_watertight=False)) == 1, f"{category} {seed} has floating parts"
