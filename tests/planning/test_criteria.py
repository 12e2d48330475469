"""The next-view criteria on meshes and cameras whose answers are known by hand."""

import math

import numpy as np
import trimesh

from ushape.data.cameras import look_at
from ushape.planning.criteria import (
    angular_gap,
    uncertain_surface,
    unseen_uncertain_surface,
    vertex_areas,
    visible_from,
)


def test_vertex_areas_share_each_face_in_thirds():
    # The unit square as two triangles split along the diagonal 0-2.
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    np.testing.assert_allclose(vertex_areas(vertices, faces), [1 / 3, 1 / 6, 1 / 3, 1 / 6])


def _cameras(azimuths, fov=40.0, size=64, distance=3.0):
    K, w2c = zip(*(look_at(az, 0.0, distance, fov, size) for az in azimuths))
    return np.stack(K), np.stack(w2c), np.full((len(azimuths), 2), size)


def test_a_camera_sees_the_near_side_of_a_sphere_and_not_the_far_side():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    K, w2c, hw = _cameras([0.0, 180.0])  # on +x and on -x
    visible = visible_from(sphere, K, w2c, hw)
    x = sphere.vertices[:, 0]
    # From distance 3 a sphere of radius 0.5 is seen up to x = r^2 / d = 0.083 on the near side.
    assert visible[0][x > 0.15].all() and not visible[0][x < 0.0].any()
    assert visible[1][x < -0.15].all() and not visible[1][x > 0.0].any()


def test_what_falls_outside_the_image_is_not_seen():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    K, w2c, hw = _cameras([0.0], fov=4.0)  # a 4-degree view: about +-0.1 around the axis at x = 0.5
    visible = visible_from(sphere, K, w2c, hw)[0]
    assert visible.any() and np.abs(sphere.vertices[visible][:, 1:]).max() < 0.12


def test_uncertain_surface_sums_variance_times_area_over_what_is_seen():
    visible = np.array([[1, 1, 0], [0, 1, 1]], bool)
    variance, area = np.array([1.0, 2.0, 10.0]), np.array([0.5, 1.0, 0.1])
    np.testing.assert_allclose(uncertain_surface(visible, variance, area), [0.5 + 2.0, 2.0 + 1.0])
    seen = np.array([False, True, False])
    np.testing.assert_allclose(unseen_uncertain_surface(visible, variance, area, seen), [0.5, 1.0])


def test_angular_gap_is_the_angle_to_the_nearest_view_taken():
    directions = np.array([[1, 0, 0], [0, 0, 1], [-1, 0, 0], [1, 0, 1]], float)
    np.testing.assert_allclose(angular_gap(directions, []), [math.pi] * 4)
    np.testing.assert_allclose(angular_gap(directions, [0]), [0, math.pi / 2, math.pi, math.pi / 4], atol=1e-7)
    np.testing.assert_allclose(angular_gap(directions, [0, 2]), [0, math.pi / 2, 0, math.pi / 4], atol=1e-7)
