"""R2N2 camera protocol: known answers for projection, pose, metadata round trip."""

import math

import numpy as np
import pytest

from ushape.data.cameras import (
    R2N2_FOV_DEG,
    camera_centre,
    format_metadata,
    intrinsics,
    look_at,
    metadata_to_cameras,
    parse_metadata,
    project,
    sample_r2n2_views,
)


def test_blender_default_lens_field_of_view():
    assert R2N2_FOV_DEG == pytest.approx(49.1343, abs=1e-3)
    K = intrinsics(R2N2_FOV_DEG, 137)
    assert K[0, 0] == pytest.approx(35.0 / 32.0 * 137)  # focal in pixels = lens / sensor * width
    assert K[0, 2] == K[1, 2] == 68.5


def test_origin_projects_to_image_centre_and_pose_is_right():
    K, w2c = look_at(37.0, 27.0, 1.4, R2N2_FOV_DEG, 137)
    uv, depth = project(np.zeros((1, 3)), K, w2c)
    assert np.allclose(uv, [[68.5, 68.5]]) and depth[0] == pytest.approx(1.4)
    centre = camera_centre(w2c)
    assert np.linalg.norm(centre) == pytest.approx(1.4)
    assert math.degrees(math.asin(centre[1] / 1.4)) == pytest.approx(27.0)
    R = w2c[:3, :3]
    assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)


def test_azimuth_turns_as_r2n2s_and_opencv_axes():
    _, w2c = look_at(0.0, 0.0, 2.0, 50.0, 64)
    assert np.allclose(camera_centre(w2c), [2.0, 0.0, 0.0])
    # R2N2's rig turns by -azimuth: in ShapeNet v1's axes the camera moves from +x towards +z.
    K, w2c = look_at(90.0, 0.0, 2.0, 50.0, 64)
    assert np.allclose(camera_centre(w2c), [0.0, 0.0, 2.0])
    # Camera on +z looking at -z with y up: world +y is image up (smaller v), world +x is image right.
    uv, _ = project(np.array([[0.0, 0.5, 0.0], [0.5, 0.0, 0.0]]), K, w2c)
    assert uv[0, 1] < 32 and uv[0, 0] == pytest.approx(32)
    assert uv[1, 0] > 32 and uv[1, 1] == pytest.approx(32)


def test_v2_frame_is_v1_turned_about_y():
    # (x, y, z)_v2 = (z, y, -x)_v1: the v1 front (+x) is v2's -z, v1's +z is v2's +x.
    for az, v1_centre in ((0.0, [2.0, 0.0, 0.0]), (90.0, [0.0, 0.0, 2.0]), (30.0, None)):
        _, w2c_v1 = look_at(az, 20.0, 2.0, 50.0, 64)
        _, w2c_v2 = look_at(az, 20.0, 2.0, 50.0, 64, frame="v2")
        c1, c2 = camera_centre(w2c_v1), camera_centre(w2c_v2)
        assert np.allclose(c2, [c1[2], c1[1], -c1[0]])
        if v1_centre is not None:
            assert np.allclose(camera_centre(look_at(az, 0.0, 2.0, 50.0, 64)[1]), v1_centre)
    # A point seen by the v1 camera lands on the same pixel when both are expressed in v2's axes.
    point_v1 = np.array([[0.1, 0.3, -0.2]])
    point_v2 = point_v1[:, [2, 1, 0]] * [1.0, 1.0, -1.0]
    K, w2c_v1 = look_at(57.0, 26.0, 1.5, 49.13, 137)
    _, w2c_v2 = look_at(57.0, 26.0, 1.5, 49.13, 137, frame="v2")
    assert np.allclose(project(point_v1, K, w2c_v1)[0], project(point_v2, K, w2c_v2)[0])
    with pytest.raises(ValueError, match="frame must be one of"):
        look_at(0.0, 0.0, 2.0, 50.0, 64, frame="v3")


def test_inplane_rotation_turns_the_image():
    K, w2c = look_at(90.0, 0.0, 2.0, 50.0, 64, inplane_deg=90.0)
    uv, _ = project(np.array([[0.0, 0.5, 0.0]]), K, w2c)
    # With the image axes turned 90 degrees, world up lands on the horizontal axis.
    assert uv[0, 1] == pytest.approx(32) and abs(uv[0, 0] - 32) > 5


def test_sampled_views_follow_the_protocol():
    rows = sample_r2n2_views(500, np.random.default_rng(0))
    assert rows.shape == (500, 5)
    assert rows[:, 0].min() >= 0 and rows[:, 0].max() < 360
    assert rows[:, 1].min() >= 25 and rows[:, 1].max() < 30
    assert (rows[:, 2] == 0).all()
    assert rows[:, 3].min() >= 0.65 and rows[:, 3].max() < 0.95
    assert np.allclose(rows[:, 4], R2N2_FOV_DEG)


def test_metadata_round_trip_and_framing():
    rows = sample_r2n2_views(6, np.random.default_rng(3))
    parsed = parse_metadata(format_metadata(rows))
    assert np.allclose(parsed, rows, rtol=1e-9)
    centre, scale = np.array([0.1, -0.2, 0.05]), 0.5
    Ks, w2cs = metadata_to_cameras(parsed, 137, r2n2_centre=centre, r2n2_scale=scale)
    assert Ks.shape == (6, 3, 3) and w2cs.shape == (6, 4, 4)
    distances = np.linalg.norm(camera_centre(w2cs) - centre, axis=1)
    assert np.allclose(distances, parsed[:, 3] * 1.75 / scale)
    for K, w2c in zip(Ks, w2cs):
        assert np.allclose(project(centre[None], K, w2c)[0], [[68.5, 68.5]])


def test_metadata_fov_column_and_errors():
    rows = np.array([[10.0, 26.0, 0.0, 0.8, 25.0]])  # R2N2 files carry 25 in the last column
    K_default, _ = metadata_to_cameras(rows, 137)
    K_column, _ = metadata_to_cameras(rows, 137, fov_deg=None)
    assert K_default[0, 0, 0] == pytest.approx(intrinsics(R2N2_FOV_DEG, 137)[0, 0])
    assert K_column[0, 0, 0] == pytest.approx(intrinsics(25.0, 137)[0, 0])
    with pytest.raises(ValueError, match="5 columns"):
        metadata_to_cameras(np.zeros((2, 4)), 137)
    with pytest.raises(ValueError, match="one 'az el"):
        parse_metadata("1 2 3\n")
    with pytest.raises(ValueError, match="field of view"):
        intrinsics(0.0, 10)
