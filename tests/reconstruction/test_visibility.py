"""Visibility known answers on a unit sphere seen from (0, 0, 5)."""

import numpy as np
import pytest
import torch
import trimesh

from ushape.data.cameras import look_at_extrinsics
from ushape.reconstruction.visibility import hidden_over_visible, seen_by_views, visible_vertices
from ushape.refinement.views import ObservedView


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(subdivisions=4, radius=1.0)


def test_a_sphere_shows_the_cap_inside_its_tangent_cone(sphere):
    # From distance 5 a point p of the unit sphere is visible iff p_z > 1/5 (the tangent cone).
    visible = visible_vertices(sphere, np.array([0.0, 0.0, 5.0]))
    z = sphere.vertices[:, 2]
    clear = np.abs(z - 0.2) > 0.05  # away from the horizon, where tessellation decides
    assert np.array_equal(visible[clear], z[clear] > 0.2)


def test_uncertainty_on_the_far_side_gives_a_ratio_above_one(sphere):
    w2c = look_at_extrinsics(np.array([0.0, 0.0, 5.0]), np.zeros(3))
    std = np.where(sphere.vertices[:, 2] < 0, 2.0, 1.0)  # the back half twice as uncertain
    seen = hidden_over_visible(sphere, std, w2c)
    assert seen["std_hidden_over_visible"] == pytest.approx(2.0)
    assert seen["visible_vertices"] + seen["hidden_vertices"] == len(sphere.vertices)
    flat = hidden_over_visible(sphere, np.ones(len(sphere.vertices)), w2c)
    assert flat["std_hidden_over_visible"] == pytest.approx(1.0)


def test_a_camera_on_the_surface_is_refused(sphere):
    with pytest.raises(ValueError, match="on the mesh"):
        visible_vertices(sphere, sphere.vertices[0])


def test_points_count_as_seen_where_an_observed_pixel_shows_them_unblocked(sphere):
    # Camera at (0, 0, 5) looking at the origin, 64 px, f = 64: the sphere's image is a disc of radius ~13 px.
    w2c = look_at_extrinsics(np.array([0.0, 0.0, 5.0]), np.zeros(3))
    K = np.array([[64.0, 0.0, 32.0], [0.0, 64.0, 32.0], [0.0, 0.0, 1.0]])
    view = ObservedView(K=K, world_to_cam=w2c, mask=torch.zeros(64, 64))
    points = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.02], [0.0, 0.0, 0.99], [0.0, 0.0, 0.9]])
    # front pole, back pole (behind the sphere), just outside, the skin under the surface (within the
    # tolerance), well inside (more than the tolerance behind the surface)
    assert seen_by_views(sphere, points, [view]).tolist() == [True, False, True, True, False]
    assert seen_by_views(sphere, points, []).tolist() == [False] * 5
    behind = ObservedView(K=K, world_to_cam=look_at_extrinsics(np.array([0.0, 0.0, -5.0]), np.zeros(3)), mask=view.mask)
    assert seen_by_views(sphere, points, [view, behind]).tolist() == [True, True, True, True, False]
    # A crop that never observed the top half of the image: the front pole projects to the centre row 32,
    # so a view observing only rows >= 33 does not see it.
    observed = torch.zeros(64, 64, dtype=torch.bool)
    observed[33:] = True
    cut = ObservedView(K=K, world_to_cam=w2c, mask=view.mask, observed=observed)
    assert not seen_by_views(sphere, points[:1], [cut])[0]
    below = np.array([[0.0, -0.5, np.sqrt(0.75)]])  # lower on the sphere's front: projects below the centre
    assert seen_by_views(sphere, below, [cut])[0]
