"""Ray-cast renders: a sphere's silhouette and depth by hand, transparent background, shading, colours."""

import math

import numpy as np
import pytest
import trimesh

from ushape.data.cameras import R2N2_FOV_DEG, look_at
from ushape.data.rendering import RayCaster, face_and_vertex_normals, pixel_rays, render_mesh, render_views
from ushape.data.shading import Lighting, constant_colour_fn, mesh_colour_fn

RADIUS, DISTANCE, SIZE = 0.5, 1.5, 137


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(subdivisions=5, radius=RADIUS)


@pytest.fixture(scope="module")
def camera():
    return look_at(40.0, 28.0, DISTANCE, R2N2_FOV_DEG, SIZE)


def test_sphere_silhouette_and_depth(sphere, camera):
    K, w2c = camera
    out = render_mesh(sphere, K, w2c, SIZE)
    # A sphere projects to a disc of radius f * r / sqrt(d^2 - r^2).
    disc = math.pi * (K[0, 0] * RADIUS / math.sqrt(DISTANCE**2 - RADIUS**2)) ** 2
    assert out["mask"].sum() == pytest.approx(disc, rel=0.02)
    centre = SIZE // 2  # pixel 68's centre (68.5) is the principal point
    assert out["depth"][centre, centre] == pytest.approx(DISTANCE - RADIUS, abs=2e-3)
    assert out["depth"][out["mask"]].max() < DISTANCE


def test_background_is_transparent_and_outputs_agree(sphere, camera):
    out = render_mesh(sphere, *camera, SIZE)
    rgba, mask, depth = out["rgba"], out["mask"], out["depth"]
    assert rgba.dtype == np.uint8 and rgba.shape == (SIZE, SIZE, 4)
    assert mask.dtype == bool and depth.dtype == np.float32
    assert (rgba[~mask] == 0).all() and (rgba[mask, 3] == 255).all()
    assert (depth[~mask] == 0).all() and (depth[mask] > 0).all()
    assert not mask[0].any() and not mask[:, 0].any()


def test_shading_is_not_flat(sphere, camera):
    out = render_mesh(sphere, *camera, SIZE, constant_colour_fn((0.8, 0.8, 0.8)))
    grey = out["rgba"][..., 0].astype(float)
    inside = out["mask"]
    assert grey[inside].std() > 10
    # The rim is lit at grazing angles, so it is darker than the centre facing the headlight.
    rim = inside & (out["depth"] > DISTANCE - RADIUS**2 / DISTANCE - 0.04)  # silhouette depth is d - r^2/d
    assert rim.sum() > 20
    assert grey[rim].mean() < grey[SIZE // 2, SIZE // 2]
    # A white headlight highlight shows the form of dark materials too.
    black = render_mesh(sphere, *camera, SIZE, constant_colour_fn((0.02, 0.02, 0.02)))["rgba"][..., 0]
    assert int(black[SIZE // 2, SIZE // 2]) - int(black[rim].max()) > 20


def test_colour_functions(sphere, camera):
    matte = Lighting(specular=0.0)
    out = render_mesh(sphere, *camera, SIZE, constant_colour_fn((1.0, 0.0, 0.0)), lighting=matte)
    assert (out["rgba"][out["mask"], 1:3] == 0).all() and out["rgba"][out["mask"], 0].min() > 0
    painted = sphere.copy()
    painted.visual.face_colors = np.tile([0, 200, 0, 255], (len(painted.faces), 1))
    assert mesh_colour_fn(sphere) is None or mesh_colour_fn(painted) is not None
    out = render_mesh(painted, *camera, SIZE, lighting=matte)  # colour_fn=None uses the mesh's own face colours
    rgb = out["rgba"][out["mask"], :3]
    assert (rgb[:, [0, 2]] == 0).all() and rgb[:, 1].max() > 100


def test_render_views_stacks_and_rays_pass_pixel_centres(sphere):
    Ks, w2cs = zip(*(look_at(az, 25.0, 1.6, 50.0, (21, 31)) for az in (0, 120, 240)))
    out = render_views(sphere, np.stack(Ks), np.stack(w2cs), (21, 31))
    assert out["rgba"].shape == (3, 21, 31, 4) and out["mask"].shape == out["depth"].shape == (3, 21, 31)
    origins, dirs = pixel_rays(Ks[0], w2cs[0], (21, 31))
    assert origins.shape == dirs.shape == (651, 3)
    # Row-major pixels: ray of pixel (row 10, col 15) hits the principal point, i.e. the origin direction.
    centre_dir = dirs[10 * 31 + 15]
    assert np.allclose(np.cross(centre_dir, -origins[0]), 0, atol=1e-9)


def test_bad_inputs(sphere, camera):
    with pytest.raises(ValueError, match="no faces"):
        render_mesh(trimesh.Trimesh(), *camera, SIZE)
    with pytest.raises(ValueError, match="K \\[3,3\\]"):
        render_mesh(sphere, np.eye(4), camera[1], SIZE)


def test_missing_embree_is_a_clear_error(sphere, monkeypatch):
    monkeypatch.setattr(trimesh.ray, "has_embree", False)
    with pytest.raises(ImportError, match="pip install embreex"):
        RayCaster(sphere)


def test_normals_point_outwards_on_a_sphere(sphere):
    faces_n, vertex_n = face_and_vertex_normals(np.asarray(sphere.vertices), np.asarray(sphere.faces))
    assert np.allclose(vertex_n, sphere.vertices / RADIUS, atol=5e-3)  # area weighting on a near-uniform sphere
    assert np.allclose(faces_n, sphere.face_normals, atol=1e-9)
