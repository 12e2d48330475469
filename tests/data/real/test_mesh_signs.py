"""Signs of real-style meshes: known answers on meshes built here, and the pieces the sign test is made of."""

import igl
import numpy as np
import pytest
import trimesh

from ushape.data.real import sign_cases
from ushape.data.real.mesh_sdf import MeshProcessingError, MeshSdf, SignReport, sample_mesh_sdf
from ushape.data.real.mesh_signs import (
    INSIDE_ESCAPE,
    MeshSigns,
    clean_triangles,
    escape_fraction,
    hemisphere_directions,
    orient_surface,
    orientable_patches,
)
from ushape.data.sampling import sample_points


def away_from_surface(mesh, points, margin=0.01):
    """Bool [N]: the point is at least `margin` from every triangle."""
    squared, _, _ = igl.point_mesh_squared_distance(
        points, np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    )
    return squared >= margin**2


@pytest.mark.parametrize("make", sign_cases.KNOWN_ANSWER_CASES, ids=lambda f: f.__name__)
def test_known_answer_meshes_get_their_stated_signs(make):
    case = make()
    points = sample_points(case.mesh, 4000, np.random.default_rng(0))
    away = away_from_surface(case.mesh, points)
    inside = MeshSigns(case.mesh).inside(points[away])
    assert away.sum() > 2500
    assert np.mean(inside == case.solid(points[away])) >= 0.99, case.answer


@pytest.mark.parametrize(
    "make, deep_point",
    [
        (sign_cases.cabinet, [0.3, 0.33, -0.43]),  # at the back of the upper right cubby
        (sign_cases.drawer_table, [0.0, 0.31, -0.2]),  # at the back of the shallow drawer
    ],
)
def test_deep_compartments_are_outside_although_few_rays_escape(make, deep_point):
    case = make()
    point = np.array([deep_point])
    assert not case.solid(point)[0]
    signs = MeshSigns(case.mesh)
    # The ray-escape test alone would call these points inside: that was issue #18.
    escape = escape_fraction(case.mesh, np.repeat(point, 100, axis=0), 32, np.random.default_rng(0))
    assert escape.mean() < INSIDE_ESCAPE
    assert abs(signs.winding_number(point)[0]) < 0.01
    assert not signs.inside(point)[0]


def test_closed_and_enclosed_meshes_are_fully_confident():
    for make in (sign_cases.cabinet, sign_cases.drawer_table, sign_cases.broken_soup):
        case = make()
        sdf = MeshSdf(case.mesh)
        sdf.inside(sample_points(case.mesh, 3000, np.random.default_rng(1)))
        report = SignReport.of(sdf.signs)
        assert report.confidence > 0.99 and report.leak == 0.0, case.name


def test_open_meshes_are_flagged_by_their_report():
    # A box missing a whole side is a block without its lid or a container: no method can know.
    # Its samples get signs, but the report tells a user filtering the dataset that they rest on judgement.
    case = sign_cases.open_box()
    assert case.solid is None
    sdf = MeshSdf(case.mesh)
    sdf.inside(sample_points(case.mesh, 3000, np.random.default_rng(1)))
    report = SignReport.of(sdf.signs)
    assert report.confidence < 0.8 and report.leak > 0.05


def test_low_confidence_is_rejected_with_the_reason(rng):
    with pytest.raises(MeshProcessingError, match="inconclusive.*too open"):
        sample_mesh_sdf(sign_cases.open_box().mesh, 2000, rng, min_confidence=0.9)


def test_clean_triangles_merges_vertices_and_drops_duplicate_and_degenerate_faces():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, 1], [2, 0, 0]], float)
    faces = np.array(
        [
            [0, 1, 2],  # kept
            [0, 2, 3],  # the same triangle the other way round (vertex 3 == vertex 1): dropped
            [0, 1, 4],  # kept
            [0, 1, 5],  # zero area (collinear): dropped
            [0, 3, 4],  # the same as [0, 1, 4] once vertices merge: dropped
        ]
    )
    v, f = clean_triangles(vertices, faces)
    assert len(v) == 5
    triangles = {frozenset(map(tuple, v[face])) for face in f}
    assert triangles == {frozenset({(0, 0, 0), (1, 0, 0), (0, 1, 0)}), frozenset({(0, 0, 0), (1, 0, 0), (0, 0, 1)})}
    assert len(f) == 2


def test_patches_make_winding_consistent_and_know_closed_from_open():
    tetra = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])  # consistently wound, closed
    shuffled = tetra.copy()
    shuffled[[1, 3]] = shuffled[[1, 3]][:, ::-1]
    labels, flip, closed = orientable_patches(shuffled)
    fixed = shuffled.copy()
    fixed[flip] = fixed[flip][:, ::-1]
    assert len(closed) == 1 and closed[0]
    # Every directed edge of a consistently wound closed surface appears exactly once.
    directed = {tuple(e) for e in fixed[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)}
    assert len(directed) == 12
    strip = np.array([[0, 1, 2], [2, 1, 3], [4, 5, 6]])  # two joined triangles and a separate one
    labels, _, closed = orientable_patches(strip)
    assert labels[0] == labels[1] != labels[2] and not closed.any()


def test_non_manifold_edge_separates_patches():
    # Three triangles on the edge (0, 1): none of them is joined across it.
    fan = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    labels, _, _ = orientable_patches(fan)
    assert len(set(labels)) == 3


def test_orientation_turns_inside_out_boxes_and_drops_hidden_sheets():
    outer = trimesh.creation.box(extents=(1, 1, 1))
    inner_sheet = trimesh.Trimesh([[-0.2, -0.2, 0], [0.2, -0.2, 0], [0, 0.2, 0]], [[0, 1, 2]])
    open_lid = trimesh.creation.box(
        extents=(0.3, 0.3, 0.3), transform=trimesh.transformations.translation_matrix([2, 0, 0])
    )
    open_lid = trimesh.Trimesh(open_lid.vertices, open_lid.faces[2:][:, ::-1], process=False)  # open and inside-out
    inverted = trimesh.Trimesh(outer.vertices, outer.faces[:, ::-1], process=False)
    mesh = trimesh.util.concatenate([inverted, inner_sheet, open_lid])
    vertices, faces = clean_triangles(mesh.vertices, mesh.faces)
    surface = orient_surface(vertices, faces, np.random.default_rng(0))
    assert (surface.patches, surface.closed_patches, surface.hidden_patches) == (3, 1, 1)
    corners = vertices[surface.faces]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    outward = np.einsum("ij,ij->i", normals, corners.mean(axis=1) - np.where(corners[:, :1, 0] > 1.5, [2, 0, 0], 0))
    assert np.all(outward > 0)


def test_hemisphere_directions_are_unit_and_on_the_normal_side(rng):
    normals = rng.normal(size=(50, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    directions = hemisphere_directions(normals, 16, rng)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=2), 1.0, atol=1e-12)
    cosines = np.einsum("prj,pj->pr", directions, normals)
    assert cosines.min() > 0 and abs(cosines.mean() - 0.5) < 0.05  # uniform on a hemisphere: mean cosine 1/2


def test_sign_benchmark_prints_the_known_answer_table(capsys):
    from ushape.data.real import mesh_sdf_bench

    assert mesh_sdf_bench.main(["--samples", "2000"]) == 0
    table = capsys.readouterr().out
    rows = {line.split(" | ")[0].strip("| "): line.split(" | ") for line in table.splitlines() if line.startswith("| ")}
    assert set(rows) >= {case().name for case in sign_cases.KNOWN_ANSWER_CASES}
    assert rows["cabinet with open cubbies"][3] == "1.0000"  # the current method's column
