"""Signs of real-style meshes: known answers on meshes built here, and the pieces the sign test is made of."""

import igl
import numpy as np
import pytest
import trimesh

from ushape.data.real import sign_cases
from ushape.data.real.mesh_orientation import (
    clean_triangles,
    hemisphere_directions,
    orient_surface,
    orientable_patches,
    winding_number,
)
from ushape.data.real.mesh_sdf import MeshProcessingError, MeshSdf, SignReport, sample_mesh_sdf
from ushape.data.real.mesh_signs import escape_fraction
from ushape.data.sampling import sample_points


def away_from_surface(mesh, points, margin=0.01):
    """Bool [N]: the point is at least `margin` from every triangle."""
    squared, _, _ = igl.point_mesh_squared_distance(
        points, np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    )
    return squared >= margin**2


def report_of(mesh, n=3000, seed=1, **options):
    sdf = MeshSdf(mesh, **options)
    sdf.inside(sample_points(mesh, n, np.random.default_rng(seed)))
    return SignReport.of(sdf.signs)


@pytest.mark.parametrize("make", sign_cases.KNOWN_ANSWER_CASES, ids=lambda f: f.__name__)
def test_known_answer_meshes_get_their_stated_signs(make):
    case = make()
    points = sample_points(case.mesh, 4000, np.random.default_rng(0))
    away = away_from_surface(case.mesh, points)
    inside = MeshSdf(case.mesh).inside(points[away])
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
    # The ray-escape test alone would call these points inside; a path from outside reaches them.
    escape = escape_fraction(case.mesh, np.repeat(point, 100, axis=0), 32, np.random.default_rng(0))
    assert escape.mean() < 0.05
    assert not MeshSdf(case.mesh).inside(point)[0]


def test_sealed_hollow_is_inside_although_its_winding_number_is_zero_and_no_ray_escapes():
    case = sign_cases.sealed_box_table()
    point = np.array([[0.2, 0.4, 0.1]])  # in the hollow between the six plates
    assert case.solid(point)[0]
    vertices, faces = clean_triangles(case.mesh.vertices, case.mesh.faces)
    surface = orient_surface(vertices, faces, np.random.default_rng(0))
    assert abs(winding_number(vertices, surface.faces, point)[0]) < 0.01
    assert escape_fraction(case.mesh, point, 256, np.random.default_rng(0))[0] == 0.0
    assert MeshSdf(case.mesh).inside(point)[0]


def test_closed_and_enclosed_meshes_are_fully_confident():
    for make in (sign_cases.cabinet, sign_cases.drawer_table, sign_cases.broken_soup, sign_cases.doubled_soup_chair):
        report = report_of(make().mesh)
        assert report.confidence > 0.99 and report.resolution_agreement == 1.0, make.__name__


@pytest.mark.parametrize(
    "make", [sign_cases.sealed_box_table, sign_cases.open_seat_chair, sign_cases.sieve_sphere, sign_cases.open_box]
)
def test_meshes_whose_sign_depends_on_the_method_are_flagged(make):
    # Sealed hollows and open insides: the winding number gives the other sign to many far samples.
    report = report_of(make().mesh)
    assert report.confidence < 0.9 and report.winding_agreement < 0.9


def plate_box_with_slit(width):
    """A hollow closed box of six plates (1.2 x 0.6 x 0.8, 0.04 thick) whose top plate is cut by a slit across x."""
    x0, x1, y0, y1, z0, z1, t = -0.6, 0.6, -0.3, 0.3, -0.4, 0.4, 0.04
    plates = [
        ((x0, y1 - t, z0), (-width / 2, y1, z1)),
        ((width / 2, y1 - t, z0), (x1, y1, z1)),  # the top, in two halves
        ((x0, y0, z0), (x1, y0 + t, z1)),
        ((x0, y0 + t, z0), (x0 + t, y1 - t, z1)),
        ((x1 - t, y0 + t, z0), (x1, y1 - t, z1)),
        ((x0 + t, y0 + t, z0), (x1 - t, y1 - t, z0 + t)),
        ((x0 + t, y0 + t, z1 - t), (x1 - t, y1 - t, z1)),
    ]
    return sign_cases.union_of_closed_boxes(plates)


def test_a_slit_open_at_one_resolution_and_sealed_at_the_other_is_flagged():
    # Voxels of 0.0047 and 0.0190: a slit of 0.012 lets the fine grid's fill in, the coarse grid seals it.
    hollow = np.array([[0.2, 0.0, 0.1]])
    mesh = plate_box_with_slit(0.012)
    assert not MeshSdf(mesh).inside(hollow)[0]
    assert MeshSdf(mesh, resolution=64, check_resolution=64).inside(hollow)[0]
    report = report_of(mesh, check_resolution=64)
    assert report.resolution_agreement < 0.9 and report.confidence < 0.9
    sealed = report_of(plate_box_with_slit(0.0), check_resolution=64)
    assert sealed.resolution_agreement == 1.0


def test_a_crack_narrower_than_a_voxel_is_sealed():
    # The official voxels close gaps under a voxel; so does the grid, at its own resolution.
    assert MeshSdf(plate_box_with_slit(0.002)).inside(np.array([[0.2, 0.0, 0.1]]))[0]


def test_open_meshes_enclose_nothing_and_are_rejected(rng):
    # A box missing a whole side, a seat open at the back: reachable inside, so outside, as their hollow voxels.
    for case in (sign_cases.open_box(), sign_cases.open_seat_chair()):
        points = sample_points(case.mesh, 3000, rng)
        inside = MeshSdf(case.mesh).inside(points)
        legs = sign_cases.in_boxes(sign_cases._legs(-0.05, 0.34, 0.34))(points)
        assert not inside[~legs].any(), case.name
    with pytest.raises(MeshProcessingError, match="encloses no volume"):
        sample_mesh_sdf(sign_cases.open_box().mesh, 2000, rng)


def test_low_confidence_is_rejected_with_the_reason_when_asked(rng):
    with pytest.raises(MeshProcessingError, match="depend on the method"):
        sample_mesh_sdf(sign_cases.sealed_box_table().mesh, 2000, rng, min_confidence=0.9)


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
