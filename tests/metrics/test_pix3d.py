"""Known answers of the Pix3D metrics: identical and translated point sets, spheres, scale invariance."""

import math

import numpy as np
import pytest
import trimesh

from ushape.metrics.pix3d import (
    BoxFrame,
    box_frame,
    chamfer_pix3d,
    earth_movers,
    pix3d_metrics,
    reference_from_mesh,
    unit_voxel_centres,
    voxel_iou,
    voxelise,
)


def _cloud(n=256, seed=0):
    return np.random.default_rng(seed).normal(size=(n, 3))


def _sphere_inside(radius, centre=(0.0, 0.0, 0.0)):
    return lambda p: np.linalg.norm(p - np.asarray(centre), axis=1) < radius


def test_identical_point_sets_score_zero():
    a = _cloud()
    assert chamfer_pix3d(a, a) == 0.0
    assert earth_movers(a, a.copy()[::-1]) == pytest.approx(0.0, abs=1e-12)  # order does not matter


def test_translated_copy_has_emd_equal_to_the_translation_length():
    a = _cloud()
    shift = np.array([0.3, -0.4, 0.0])  # length 0.5
    assert earth_movers(a, a + shift) == pytest.approx(0.5, abs=1e-9)
    # Nearest neighbours can only be closer than the matched copy: CD <= 2 |t|.
    assert 0 < chamfer_pix3d(a, a + shift) <= 1.0 + 1e-12


def test_chamfer_uses_plain_distances_summed_both_ways():
    a = np.zeros((1, 3))
    b = np.array([[0.0, 0.0, 2.0]])
    assert chamfer_pix3d(a, b) == pytest.approx(4.0)  # 2 + 2, not 2^2 + 2^2 and not halved


def test_emd_needs_equal_sizes_and_point_arrays():
    with pytest.raises(ValueError, match="equally many"):
        earth_movers(_cloud(10), _cloud(11))
    with pytest.raises(ValueError, match=r"\[N, 3\]"):
        chamfer_pix3d(np.zeros((4, 2)), _cloud(4))


def test_concentric_spheres_iou_is_the_volume_ratio():
    frame = BoxFrame(centre=np.zeros(3), scale=2.0)  # unit box -> [-1, 1]^3, no per-shape normalisation
    small = voxelise(_sphere_inside(0.5), frame, 64)
    large = voxelise(_sphere_inside(0.8), frame, 64)
    assert voxel_iou(small, large) == pytest.approx((0.5 / 0.8) ** 3, abs=0.02)


def test_box_frame_centres_and_scales_the_longest_side_to_one():
    points = np.array([[1.0, 2.0, 3.0], [3.0, 3.0, 3.5]])
    frame = box_frame(points)
    unit = frame.to_unit(points)
    assert frame.scale == 2.0
    np.testing.assert_allclose(unit.max(0) + unit.min(0), 0.0, atol=1e-12)
    assert (unit.max(0) - unit.min(0)).max() == pytest.approx(1.0)
    with pytest.raises(ValueError, match="single point"):
        box_frame(np.ones((3, 3)))


def test_voxel_centres_tile_the_unit_box():
    centres = unit_voxel_centres(4)
    assert centres.shape == (64, 3)
    assert centres.min() == pytest.approx(-0.375) and centres.max() == pytest.approx(0.375)


def test_pix3d_metrics_ignore_scale_and_position():
    gt = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    reference = reference_from_mesh(gt)
    moved = gt.copy()
    moved.apply_scale(1.7)
    moved.apply_translation([0.2, -0.1, 0.05])
    inside = _sphere_inside(0.5 * 1.7, (0.2, -0.1, 0.05))
    scores = pix3d_metrics(moved, inside, reference)
    assert scores["iou"] > 0.97
    # Two independent 1024-point samples of the same unit-box sphere: small but non-zero distances.
    assert 0 < scores["cd"] < 0.08 and 0 < scores["emd"] < 0.06


def test_pix3d_metrics_tell_a_sphere_from_a_box():
    reference = reference_from_mesh(trimesh.creation.icosphere(subdivisions=3, radius=0.5))
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    scores = pix3d_metrics(box, lambda p: np.abs(p).max(axis=1) < 0.5, reference)
    assert scores["iou"] == pytest.approx(math.pi / 6, abs=0.03)  # unit ball in a unit cube
    assert scores["emd"] > 0.03
