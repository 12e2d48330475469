"""Marching cubes on analytic SDFs: grid convention, dense vs coarse-to-fine, empty surfaces."""

import numpy as np
import pytest
import torch

from ushape.mesh.extraction import EmptySurfaceError, extract_mesh, grid_coordinates, sdf_grid


def sphere(radius, centre=(0.0, 0.0, 0.0)):
    c = torch.tensor(centre)
    return lambda p: (p - c).norm(dim=-1) - radius


def box(half_extents, centre=(0.0, 0.0, 0.0)):
    h, c = torch.tensor(half_extents), torch.tensor(centre)

    def sdf(p):
        q = (p - c).abs() - h
        return q.clamp(min=0).norm(dim=-1) + q.max(dim=-1).values.clamp(max=0)

    return sdf


def chair_like(p):
    """A seat, a back and four thin legs: the thin parts are what coarse grids miss."""
    parts = [box((0.4, 0.03, 0.4), (0, 0, 0)), box((0.4, 0.4, 0.03), (0, 0.43, -0.37))]
    parts += [box((0.02, 0.3, 0.02), (x, -0.33, z)) for x in (-0.37, 0.37) for z in (-0.37, 0.37)]
    return torch.stack([part(p) for part in parts]).min(dim=0).values


def test_grid_points_include_both_faces_of_the_cube():
    axis = grid_coordinates(5)
    assert torch.allclose(axis, torch.tensor([-1.0, -0.5, 0.0, 0.5, 1.0]))


def test_sdf_grid_indexes_x_y_z():
    grid = sdf_grid(lambda p: p[:, 0] + 10 * p[:, 1] + 100 * p[:, 2], 3)
    assert grid[2, 0, 0] == pytest.approx(1 - 10 - 100)
    assert grid[0, 2, 1] == pytest.approx(-1 + 10)


@pytest.mark.parametrize("method", ["dense", "coarse_to_fine"])
def test_sphere_vertices_lie_on_the_sphere(method):
    mesh, _ = extract_mesh(sphere(0.5, (0.1, -0.2, 0.05)), resolution=64, method=method)
    radii = np.linalg.norm(mesh.vertices - np.array([0.1, -0.2, 0.05]), axis=1)
    voxel = 2 / 63
    assert np.abs(radii - 0.5).max() < 0.05 * voxel  # no half-voxel offset
    assert mesh.is_watertight and mesh.volume == pytest.approx(4 / 3 * np.pi * 0.125, rel=0.01)


def test_box_faces_land_where_the_box_is():
    mesh, _ = extract_mesh(box((0.3, 0.2, 0.5), (0.1, 0.0, -0.1)), resolution=64, method="dense")
    lo, hi = mesh.bounds
    assert np.allclose(lo, [-0.2, -0.2, -0.6], atol=0.02) and np.allclose(hi, [0.4, 0.2, 0.4], atol=0.02)


@pytest.mark.parametrize("sdf_fn", [sphere(0.55), chair_like], ids=["sphere", "chair_like"])
def test_coarse_to_fine_gives_the_dense_mesh_with_far_fewer_evaluations(sdf_fn):
    dense, dense_stats = extract_mesh(sdf_fn, resolution=128, method="dense")
    fast, fast_stats = extract_mesh(sdf_fn, resolution=128, method="coarse_to_fine")
    assert dense_stats.evaluations == 128**3
    assert fast.vertices.shape == dense.vertices.shape
    assert np.abs(fast.vertices - dense.vertices).max() < 1e-6
    # Faces exactly: they follow the grid's signs, and no grid value lies within 2e-4 of 0 (no cell is ambiguous),
    # far beyond the last-bit rounding other batches may give a value (what the vertices above are allowed).
    assert np.array_equal(fast.faces, dense.faces)
    assert fast_stats.saving >= 10


def test_no_zero_crossing_raises_empty_surface_error():
    for method in ("dense", "coarse_to_fine"):
        with pytest.raises(EmptySurfaceError, match="no surface"):
            extract_mesh(lambda p: p.norm(dim=-1) + 0.1, resolution=32, method=method)
    assert issubclass(EmptySurfaceError, ValueError)


def test_numpy_returning_sdf_is_accepted():
    mesh, _ = extract_mesh(lambda p: np.linalg.norm(p.numpy(), axis=1) - 0.5, resolution=32, method="dense")
    assert len(mesh.faces) > 0


def test_unknown_method_is_rejected():
    with pytest.raises(ValueError, match="dense"):
        extract_mesh(sphere(0.5), resolution=16, method="octree")


def test_resolution_below_the_coarse_grid_still_meshes():
    sphere = lambda p: p.norm(dim=-1) - 0.5  # noqa: E731
    dense, _ = extract_mesh(sphere, 16, method="dense")
    small, _ = extract_mesh(sphere, 16, method="coarse_to_fine", coarse_resolution=32)
    assert np.allclose(np.sort(small.vertices, 0), np.sort(dense.vertices, 0))


@pytest.mark.parametrize("method", ["dense", "coarse_to_fine"])
def test_surface_fn_places_every_vertex_from_the_exact_sdf(method):
    """An approximation off by 0.3 of a cell still decides where to look; the exact SDF places the vertices."""
    exact = chair_like
    voxel = 2.0 / 47

    def approximate(p):  # wrong by up to 0.3 of a cell, as bf16's rounded query points make a decoder
        return exact(p) + 0.3 * voxel * torch.sin(40.0 * p).sum(dim=-1) / 3

    reference, _ = extract_mesh(exact, 48, method)
    raw, raw_stats = extract_mesh(approximate, 48, method)
    fixed, stats = extract_mesh(approximate, 48, method, surface_fn=exact)
    assert raw.vertices.shape != reference.vertices.shape or not np.allclose(raw.vertices, reference.vertices)
    # Faces exactly: every sign is the exact SDF's, and no grid value lies within 2e-4 of 0 (no ambiguous cell),
    # so the re-evaluation's batches, which may round a value differently, cannot change a face.
    assert np.array_equal(fixed.faces, reference.faces)
    assert np.allclose(fixed.vertices, reference.vertices, atol=1e-6)
    assert stats.evaluations > raw_stats.evaluations  # the exact evaluations are counted


def test_marched_corners_of_one_inside_point_are_its_six_neighbours():
    from ushape.mesh.extraction import marched_corners, surface_cell_corners

    grid = torch.ones(3, 3, 3)
    grid[1, 1, 1] = -1.0
    expected = torch.zeros(3, 3, 3, dtype=torch.bool)
    for offset in ((0, 0, 0), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)):
        expected[1 + offset[0], 1 + offset[1], 1 + offset[2]] = True
    assert torch.equal(marched_corners(grid), expected)
    assert bool(surface_cell_corners(grid).all())  # every cell changes sign; its 20 other corners are not read


def test_a_cell_with_an_ambiguous_face_has_all_its_corners_marched():
    from ushape.mesh.extraction import marched_corners

    grid = torch.ones(3, 3, 3)
    grid[0, 0, 0] = grid[1, 1, 0] = -1.0  # the face z = 0 of cell (0, 0, 0) alternates its signs
    ends = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (2, 1, 0), (1, 2, 0), (1, 1, 1)]
    far_corners = [(1, 0, 1), (0, 1, 1)]  # on no sign-changing edge, but the ambiguous cell's
    expected = torch.zeros(3, 3, 3, dtype=torch.bool)
    for point in ends + far_corners:
        expected[point] = True
    assert torch.equal(marched_corners(grid), expected)


def test_marching_cubes_reads_only_the_signs_away_from_the_marched_corners():
    """Any same-sign values off the marched corners give the same mesh, bit for bit (ambiguous cells too)."""
    from ushape.mesh.extraction import marched_corners, marching_cubes

    g = torch.Generator().manual_seed(0)
    for _ in range(8):
        coarse = torch.randn(1, 1, 4, 4, 4, generator=g)
        grid = torch.nn.functional.interpolate(coarse, size=(16,) * 3, mode="trilinear", align_corners=True)[0, 0]
        grid = grid + 0.05 * torch.randn(grid.shape, generator=g)  # noise: ambiguous faces occur
        keep = marched_corners(grid)
        other = grid.clone()
        other[~keep] = grid[~keep].sign() * (5 * torch.rand(int((~keep).sum()), generator=g) + 0.01)
        reference, mesh = marching_cubes(grid), marching_cubes(other)  # the marched corners' values are copies
        assert np.array_equal(mesh.faces, reference.faces) and np.array_equal(mesh.vertices, reference.vertices)
        assert 0 < int(keep.sum()) < keep.numel()
    moved = grid.clone()
    moved[keep.nonzero()[0].unbind()] *= 0.5  # a marched corner's value does move a vertex
    assert not np.array_equal(marching_cubes(moved).vertices, reference.vertices)


def test_exact_surface_trusts_signs_beyond_three_times_the_error_it_sees():
    """An approximation 0.04 off (away from 0): the marched corners, then the points within 0.12 of 0, no more."""
    from ushape.mesh.extraction import exact_surface, marched_corners

    grid = sdf_grid(sphere(0.5), 32)
    approximate = grid + 0.04 * grid.sign()  # the signs are right, the values are not
    assert not bool(((approximate.abs() - 0.12).abs() < 1e-5).any())  # none at the margin: rounding is moot
    evaluated = []

    def exact(p):
        evaluated.append(p.shape[0])
        return sphere(0.5)(p)

    fixed, count = exact_surface(approximate, exact, chunk=10**6)
    marched = marched_corners(grid)
    expected = marched | (approximate.abs() <= 0.12)
    assert count == int(expected.sum()) == sum(evaluated)
    assert evaluated == [int(marched.sum()), int((expected & ~marched).sum())]  # marched, then uncertain
    assert evaluated[1] > 0
    # (the points re-evaluated come in another batch and layout, where the norm may round its last bit otherwise)
    assert torch.allclose(fixed[expected], grid[expected], rtol=0, atol=1e-6)
    assert torch.equal(fixed[~expected], approximate[~expected])  # not evaluated: the stored values, untouched


def test_exact_surface_finds_a_sign_the_approximation_got_wrong():
    """A point 1e-3 outside that the approximation puts 1e-3 inside: the exact SDF's mesh."""
    from ushape.mesh.extraction import exact_surface, marching_cubes

    axis = grid_coordinates(32)
    radius = float(torch.stack([axis[24], axis[16], axis[16]]).norm()) - 1e-3
    grid = sdf_grid(sphere(radius), 32)
    approximate = grid - 2e-3
    assert bool(((approximate < 0) != (grid < 0)).any())
    fixed, _ = exact_surface(approximate, sphere(radius))
    assert bool(((fixed < 0) == (grid < 0)).all())
    reference, mesh = marching_cubes(grid), marching_cubes(fixed)
    # Faces exactly: no grid value lies within 9e-4 of 0, far beyond the rounding of the re-evaluation.
    assert np.array_equal(mesh.faces, reference.faces) and np.allclose(mesh.vertices, reference.vertices, atol=1e-6)


def test_exact_surface_rejects_a_safety_below_one():
    from ushape.mesh.extraction import exact_surface

    with pytest.raises(ValueError, match="safety"):
        exact_surface(sdf_grid(sphere(0.5), 8), sphere(0.5), safety=0.5)
