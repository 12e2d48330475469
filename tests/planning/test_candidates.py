"""Candidate views: the orbit grid, re-rendering a synthetic world's own views exactly, recorded views."""

import numpy as np
import pytest
import torch

from ushape.data.augment import load_rgba
from ushape.data.cameras import parse_metadata
from ushape.data.world import SyntheticWorld
from ushape.planning.candidates import (
    candidate_views,
    orbit_rows,
    orbit_views,
    recorded_views,
    spread_elevations,
)


@pytest.fixture(scope="module")
def chair_world(tmp_path_factory):
    """One real procedural chair per split that has one, rendered from 3 views at 32 px."""
    root = tmp_path_factory.mktemp("chairs")
    tiny = dict(n_train=1, n_val=0, n_test=1, samples_per_shape=200, n_views=3, image_size=32, mesh_resolution=48)
    return SyntheticWorld("chairs", str(root), **tiny).build()


def test_the_orbit_grid_crosses_azimuths_with_elevations():
    rows = orbit_rows(4, [25.0, 30.0], 0.8)
    assert rows.shape == (8, 5)
    np.testing.assert_allclose(rows[:4, 0], [0, 90, 180, 270])
    np.testing.assert_allclose(rows[:, 1], [25.0] * 4 + [30.0] * 4)
    assert (rows[:, 3] == 0.8).all() and (rows[:, 2] == 0).all()
    assert spread_elevations(1) == [27.5] and spread_elevations(3) == [25.0, 27.5, 30.0]
    with pytest.raises(ValueError, match="n_azimuth"):
        orbit_rows(0, [25.0])


def test_orbit_views_rerender_the_worlds_own_views(chair_world):
    shape_id = chair_world.shape_ids("test")[0]
    rows = parse_metadata(chair_world.metadata_path(shape_id).read_text())
    views = orbit_views(chair_world, shape_id, rows=rows)
    for view in range(len(rows)):
        # Its cameras come from views.npz's float32 frame (8e-8 from the build's float64 one): a pixel on a
        # silhouette or on a colour's rounding edge may turn, nothing more. Another view differs in 100+ pixels.
        rendered, stored = views.image(view), load_rgba(chair_world.image_path(shape_id, view))
        assert int(((rendered - stored).abs().amax(0) > 1.5 / 255).sum()) <= 2
    with np.load(chair_world.views_path(shape_id)) as cams:
        np.testing.assert_allclose(views.world_to_cam, cams["world_to_cam"], atol=1e-5)


def test_orbit_candidates_sit_where_their_rows_say(chair_world):
    shape_id = chair_world.shape_ids("test")[0]
    views = candidate_views(chair_world, shape_id, "auto", n_azimuth=6, n_elevation=2)
    assert views.source == "orbit" and len(views) == 12
    angles = views.azimuth_elevation()
    np.testing.assert_allclose(angles[:6, 0], np.arange(0, 360, 60), atol=1e-6)
    np.testing.assert_allclose(angles[:, 1], [25.0] * 6 + [30.0] * 6, atol=1e-6)
    image = views.image(3)
    assert image.shape == (4, 32, 32) and 0.02 < image[3].mean() < 0.9  # the chair is in the picture
    assert (views.image_hw == 32).all()


def test_recorded_views_are_the_worlds_views(sphere_world):
    shape_id = sphere_world.shape_ids("test")[0]
    views = candidate_views(sphere_world, shape_id)  # not a synthetic world: its own views
    assert views.source == "recorded" and len(views) == sphere_world.view_count(shape_id)
    assert torch.equal(views.image(2), load_rgba(sphere_world.image_path(shape_id, 2)))  # the file, read twice
    np.testing.assert_allclose(views.azimuth_elevation()[:3], [[0, 20], [45, 20], [90, 20]], atol=1e-5)
    with pytest.raises(ValueError, match="candidates=recorded"):
        orbit_views(sphere_world, shape_id)
    with pytest.raises(IndexError):
        views.image(len(views))
    with pytest.raises(ValueError, match="one of"):
        candidate_views(sphere_world, shape_id, "nearby")
    assert recorded_views(sphere_world, shape_id).K.shape == (len(views), 3, 3)
