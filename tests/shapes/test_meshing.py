"""Narrow-band marching cubes on known SDFs: watertight, outward, and equal to a dense grid."""

import numpy as np
import pytest
from skimage.measure import marching_cubes

from ushape.shapes.meshing import grid_spacing, mesh_from_sdf, sdf_volume

CENTRE = np.array([0.1, -0.05, 0.0])
LO, HI = CENTRE - 0.5, CENTRE + 0.5


def sphere(p):
    return np.linalg.norm(p - CENTRE, axis=1) - 0.5


def test_sphere_mesh_is_watertight_outward_and_on_the_surface():
    mesh = mesh_from_sdf(sphere, LO, HI, resolution=64)
    h = grid_spacing(LO, HI, 64)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # outward normals
    assert mesh.volume == pytest.approx(4 / 3 * np.pi * 0.5**3, rel=0.01)
    radii = np.linalg.norm(mesh.vertices - CENTRE, axis=1)
    assert np.abs(radii - 0.5).max() < 0.5 * h


def test_sparse_volume_has_dense_signs_and_dense_mesh():
    vol, origin, h, mask = sdf_volume(sphere, LO, HI, resolution=48)
    grid = np.argwhere(np.ones(vol.shape, dtype=bool))
    dense = sphere(origin + grid * h).reshape(vol.shape).astype(np.float32)
    # Exact: both evaluate the same float64 expression at each corner (elementwise ufuncs and a three-term sum in
    # numpy's fixed order), and the far cells' signs come with the half-diagonal's margin.
    assert np.array_equal(np.sign(vol), np.sign(dense))
    v_sparse, f_sparse, _, _ = marching_cubes(vol, 0.0, spacing=(h, h, h), mask=mask)
    v_dense, f_dense, _, _ = marching_cubes(dense, 0.0, spacing=(h, h, h))
    np.testing.assert_allclose(v_sparse, v_dense, atol=1e-6)
    assert np.array_equal(f_sparse, f_dense)
    assert mask.sum() < 0.5 * mask.size  # it really skipped most of the grid


def test_grid_origin_maps_index_to_position():
    """Vertex positions are origin + index * spacing: a plane x = c is recovered exactly."""
    c = 0.0123

    def slab(p):  # |x - c| <= 0.2, a box in y and z
        return np.maximum(np.abs(p[:, 0] - c) - 0.2, np.abs(p[:, 1:]).max(1) - 0.3)

    mesh = mesh_from_sdf(slab, np.array([c - 0.2, -0.3, -0.3]), np.array([c + 0.2, 0.3, 0.3]), resolution=40)
    xs = mesh.vertices[:, 0]
    assert xs.max() == pytest.approx(c + 0.2, abs=1e-6) and xs.min() == pytest.approx(c - 0.2, abs=1e-6)


def test_bad_input_errors():
    with pytest.raises(ValueError, match="at least 16"):
        mesh_from_sdf(sphere, LO, HI, resolution=8)
    with pytest.raises(ValueError, match="positive on the whole grid"):
        mesh_from_sdf(lambda p: np.ones(len(p)), LO, HI, resolution=32)
