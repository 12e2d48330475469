"""Known answers for Chamfer distance and volumetric IoU."""

import numpy as np
import pytest
import trimesh

from ushape.metrics.reconstruction import (
    EmptyOccupancyError,
    chamfer_deepsdf,
    iou_from_occupancy,
    mesh_inside_fn,
    sdf_inside_fn,
    volumetric_iou,
)


def ball(radius):
    return lambda p: np.linalg.norm(p, axis=1) < radius


def test_iou_of_concentric_balls_is_the_volume_ratio():
    assert volumetric_iou(ball(0.4), ball(0.6), resolution=96) == pytest.approx((0.4 / 0.6) ** 3, abs=0.01)


def test_iou_from_occupancy_counts():
    a = np.array([1, 1, 0, 0], bool)
    b = np.array([0, 1, 1, 0], bool)
    assert iou_from_occupancy(a, b) == pytest.approx(1 / 3)
    assert iou_from_occupancy(a, a) == 1.0
    with pytest.raises(EmptyOccupancyError, match="empty"):  # a ValueError too, for callers that catch those
        iou_from_occupancy(np.zeros(3, bool), np.zeros(3, bool))
    with pytest.raises(ValueError, match="shapes differ"):
        iou_from_occupancy(np.zeros(3, bool), np.zeros(4, bool))


def test_mesh_and_sdf_inside_tests_agree():
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    iou = volumetric_iou(mesh_inside_fn(mesh), sdf_inside_fn(lambda p: p.norm(dim=-1) - 0.5), resolution=48)
    assert iou > 0.97


def test_chamfer_of_identical_meshes_is_only_sampling_noise():
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    assert chamfer_deepsdf(mesh, mesh) < 2e-4


def test_chamfer_of_concentric_spheres_is_twice_the_squared_gap():
    inner = trimesh.creation.icosphere(subdivisions=5, radius=0.5)
    outer = trimesh.creation.icosphere(subdivisions=5, radius=0.6)
    assert chamfer_deepsdf(inner, outer) == pytest.approx(2 * 0.1**2, rel=0.03)


def test_chamfer_is_reproducible_with_a_seed():
    a = trimesh.creation.box((0.5, 0.5, 0.5))
    b = trimesh.creation.box((0.6, 0.5, 0.4))
    assert chamfer_deepsdf(a, b, n_points=2000, seed=3) == chamfer_deepsdf(a, b, n_points=2000, seed=3)
    assert chamfer_deepsdf(a, b, n_points=2000, seed=3) != chamfer_deepsdf(a, b, n_points=2000, seed=4)


def test_chamfer_rejects_an_empty_mesh():
    with pytest.raises(ValueError, match="no faces"):
        chamfer_deepsdf(trimesh.Trimesh(), trimesh.creation.box())


def test_open_mesh_inside_test_warns():
    open_box = trimesh.creation.box()
    open_box.update_faces(np.arange(len(open_box.faces)) > 0)
    with pytest.warns(UserWarning, match="not watertight"):
        mesh_inside_fn(open_box)
