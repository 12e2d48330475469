"""Robust SDF of real meshes: known answers on boxes, robustness to orientation/holes/duplicates, errors.

The harder known-answer meshes (cubbies, drawers, open shells) are in test_mesh_signs.py."""

import numpy as np
import pytest
import trimesh

from ushape.data.real.mesh_sdf import (
    UNIT_SPHERE_BUFFER,
    MeshProcessingError,
    MeshSdf,
    load_mesh,
    normalise_mesh,
    sample_mesh_sdf,
)


def box_sdf(points, half):
    """Exact SDF of an axis-aligned box centred at the origin."""
    q = np.abs(points) - half
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)


@pytest.fixture
def cube_points(rng):
    return rng.uniform(-0.8, 0.8, size=(3000, 3))


def test_box_sdf_is_exact(cube_points):
    half = np.array([0.3, 0.5, 0.2])
    mesh = trimesh.creation.box(extents=2 * half)
    error = np.abs(MeshSdf(mesh).sdf(cube_points) - box_sdf(cube_points, half))
    assert error.max() < 1e-9


def test_sign_ignores_orientation_duplicates_and_inner_faces(cube_points):
    half = np.array([0.4, 0.4, 0.4])
    mesh = trimesh.creation.box(extents=2 * half)
    flipped = mesh.faces.copy()
    flipped[::2] = flipped[::2, ::-1]  # half the faces wound the wrong way
    inner = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    soup = trimesh.util.concatenate([trimesh.Trimesh(mesh.vertices, flipped, process=False), mesh, inner])
    inside = MeshSdf(soup).inside(cube_points)
    expected = box_sdf(cube_points, half) < 0
    assert np.mean(inside == expected) == 1.0


def test_a_hole_opens_the_inside_however_few_rays_find_it(rng):
    # Inside is what a path from outside cannot reach (the official voxels' convention): a box with
    # a hole of two faces in its lid is hollow, as its flood-filled voxels are.
    mesh = trimesh.creation.box(extents=(1.0, 1.0, 1.0)).subdivide().subdivide().subdivide()
    lid = np.flatnonzero(mesh.face_normals[:, 1] > 0.5)
    holed = trimesh.Trimesh(mesh.vertices, np.delete(mesh.faces, lid[:2], axis=0), process=False)
    deep = rng.uniform(-0.45, 0.0, size=(500, 3))  # lower half: hardly any ray finds the hole
    assert not MeshSdf(holed).inside(deep).any()
    assert MeshSdf(mesh).inside(deep).all()


def test_normalisation_is_deepsdf_unit_sphere(make_box):
    mesh, centre, scale = normalise_mesh(make_box(extents=(0.4, 0.8, 0.3), centre=(0.1, 0.2, -0.1)))
    np.testing.assert_allclose(centre, [0.1, 0.2, -0.1], atol=1e-12)
    np.testing.assert_allclose(scale, 1.0 / (np.linalg.norm([0.2, 0.4, 0.15]) * UNIT_SPHERE_BUFFER))
    np.testing.assert_allclose(np.linalg.norm(mesh.vertices, axis=1).max(), 1 / UNIT_SPHERE_BUFFER)
    np.testing.assert_allclose(mesh.bounds.mean(axis=0), 0.0, atol=1e-12)


def test_samples_of_a_box_have_correct_signs(make_box, rng):
    mesh, _, _ = normalise_mesh(make_box())
    samples, report = sample_mesh_sdf(mesh, 4000, rng)
    half = mesh.extents / 2
    for key in ("pos", "neg"):
        rows = samples[key]
        exact = box_sdf(rows[:, :3].astype(np.float64), half)
        assert np.all(np.sign(rows[:, 3]) == np.sign(exact)) and np.abs(rows[:, 3] - exact).max() < 1e-6
    assert len(samples["neg"]) > 400 and len(samples["pos"]) + len(samples["neg"]) == 4000
    assert report.samples == 4000 and report.inside == len(samples["neg"]) / 4000
    assert report.confidence == 1.0 and report.resolution_agreement == report.winding_agreement == 1.0
    assert report.resolution == 256 and report.check_resolution == 128


def test_open_sheet_encloses_no_volume(rng):
    sheet = trimesh.Trimesh([[-0.5, 0, -0.5], [0.5, 0, -0.5], [0.5, 0, 0.5], [-0.5, 0, 0.5]], [[0, 1, 2], [0, 2, 3]])
    with pytest.raises(MeshProcessingError, match="encloses no volume"):
        sample_mesh_sdf(sheet, 2000, rng)


@pytest.mark.parametrize(
    "text, message",
    [
        ("", "no triangles"),
        ("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "degenerate"),
        ("this is not an obj file at all\n\x00\x01", "no triangles|cannot read"),
    ],
)
def test_broken_model_files_raise_mesh_processing_error(tmp_path, text, message):
    path = tmp_path / "model.obj"
    path.write_text(text)
    with pytest.raises(MeshProcessingError, match=message):
        load_mesh(path)


def test_non_finite_vertices():
    mesh = trimesh.Trimesh([[np.nan, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    with pytest.raises(MeshProcessingError, match="NaN"):
        normalise_mesh(mesh)


def test_missing_model_file(tmp_path):
    with pytest.raises(MeshProcessingError, match="does not exist"):
        load_mesh(tmp_path / "absent.obj")


def test_material_colours_become_face_colours(tmp_path):
    (tmp_path / "model.mtl").write_text("newmtl red\nKd 1 0 0\n")
    (tmp_path / "model.obj").write_text(
        "mtllib model.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nusemtl red\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
    )
    mesh = load_mesh(tmp_path / "model.obj")
    assert mesh.visual.kind == "face"
    np.testing.assert_array_equal(mesh.visual.face_colors, np.tile([255, 0, 0, 255], (4, 1)))
