"""The reachability grid: the lattice covers each triangle, the fill finds sealed hollows, free voxels touch nothing."""

import numpy as np
import pytest
from scipy import ndimage

from ushape.data.real import sign_cases
from ushape.data.real.reach_grid import ReachGrid, box_dilation, surface_lattice


@pytest.mark.parametrize(
    "triangle",
    [
        [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
        [[0, 0, 0], [1, 0, 0], [0.5, 0.003, 0.002]],  # an obtuse sliver
        [[0, 0, 0], [1, 0.01, 0], [1, -0.01, 0.02]],  # a needle
        [[0.2, 0.2, 0.2], [0.2001, 0.2, 0.2], [0.2, 0.2001, 0.2]],  # far below the spacing
    ],
)
def test_every_point_of_a_triangle_is_near_a_lattice_point(triangle, rng):
    corners = np.asarray(triangle, float)[None]
    spacing = 0.02
    lattice = np.concatenate(list(surface_lattice(corners, spacing)))
    u, v = rng.random(20000), rng.random(20000)
    fold = u + v > 1
    u[fold], v[fold] = 1 - u[fold], 1 - v[fold]
    tri = corners[0]
    points = tri[0] + u[:, None] * (tri[1] - tri[0]) + v[:, None] * (tri[2] - tri[0])
    gap = np.sqrt(((points[:, None, :] - lattice[None]) ** 2).sum(axis=2)).min(axis=1)
    assert gap.max() <= 1.12 * spacing
    area = np.linalg.norm(np.cross(tri[1] - tri[0], tri[2] - tri[0])) / 2
    assert len(lattice) < 3 * area / spacing**2 + 4 * np.linalg.norm(tri[1] - tri[0]) / spacing + 10


def test_box_dilation_is_the_3x3x3_dilation(rng):
    grid = rng.random((30, 20, 25)) > 0.995
    np.testing.assert_array_equal(box_dilation(grid), ndimage.binary_dilation(grid, np.ones((3, 3, 3), bool)))


def test_sealed_hollow_is_unreached_and_open_cubbies_are_reached():
    box = sign_cases.sealed_box_table().mesh
    grid = ReachGrid.build(np.asarray(box.vertices), np.asarray(box.faces), 128)
    free, exterior = grid.lookup(np.array([[0.0, 0.4, 0.0], [0.0, 0.0, 0.0], [5.0, 0.0, 0.0]]))
    assert free.all() and list(exterior) == [False, True, True]  # the hollow, under the table, beyond the grid
    cabinet = sign_cases.cabinet().mesh
    grid = ReachGrid.build(np.asarray(cabinet.vertices), np.asarray(cabinet.faces), 128)
    free, exterior = grid.lookup(np.array([[0.3, 0.33, -0.4]]))  # at the back of a deep cubby
    assert free[0] and exterior[0]


def test_free_voxels_hold_no_surface(rng):
    case = sign_cases.broken_soup()
    grid = ReachGrid.build(np.asarray(case.mesh.vertices), np.asarray(case.mesh.faces), 64)
    surface = case.mesh.sample(50000, seed=0)
    free, _ = grid.lookup(surface)
    assert not free.any()
    assert grid.free.mean() > 0.5


def test_too_coarse_a_grid_is_refused():
    box = sign_cases.box_mesh(((0, 0, 0), (1, 1, 1)))
    with pytest.raises(ValueError, match="resolution must be at least"):
        ReachGrid.build(np.asarray(box.vertices), np.asarray(box.faces), 4)


def test_a_coarsened_grid_seals_what_a_coarse_one_seals():
    box = sign_cases.sealed_box_table().mesh
    vertices, faces = np.asarray(box.vertices), np.asarray(box.faces)
    pooled = ReachGrid.build(vertices, faces, 128).coarsened(4)
    fresh = ReachGrid.build(vertices, faces, 32)
    assert pooled.resolution == 32 and pooled.pitch == pytest.approx(fresh.pitch, rel=0.15)
    points = np.random.default_rng(0).uniform(-0.8, 0.8, size=(5000, 3))
    free_pooled, exterior_pooled = pooled.lookup(points)
    free_fresh, exterior_fresh = fresh.lookup(points)
    both = free_pooled & free_fresh
    assert both.mean() > 0.5 and np.array_equal(exterior_pooled[both], exterior_fresh[both])
