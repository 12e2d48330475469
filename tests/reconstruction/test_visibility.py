"""Visibility known answers on a unit sphere seen from (0, 0, 5)."""

import numpy as np
import pytest
import trimesh

from ushape.data.cameras import look_at_extrinsics
from ushape.reconstruction.visibility import hidden_over_visible, visible_vertices


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
