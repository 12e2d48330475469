"""Meshes whose inside is known by construction, modelled the ways real CAD meshes go wrong.

Each case is a triangle mesh as a modeller might have saved it and the solid it stands for,
as a union of axis-aligned boxes, so every point's right sign is computable exactly. The right
sign is the official voxels' convention: inside when no path from outside reaches the point
without crossing a face. The tests check `ushape.data.real.mesh_signs` on them and the sign
benchmark measures old and new methods on the same meshes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
import trimesh

Box = tuple[tuple[float, float, float], tuple[float, float, float]]  # (lower corner, upper corner)


@dataclass(frozen=True)
class SignCase:
    name: str
    mesh: trimesh.Trimesh
    solid: Optional[Callable[[np.ndarray], np.ndarray]]  # points [N,3] -> bool [N]; None: no inside can be known
    answer: str  # the stated right answer, in words


def box_mesh(box: Box) -> trimesh.Trimesh:
    lo, hi = np.asarray(box[0], float), np.asarray(box[1], float)
    return trimesh.creation.box(extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2))


def in_boxes(boxes: list[Box]) -> Callable[[np.ndarray], np.ndarray]:
    """Bool [N] function: the point lies in at least one box."""
    lows, highs = np.array([b[0] for b in boxes]).reshape(-1, 3), np.array([b[1] for b in boxes]).reshape(-1, 3)

    def solid(points: np.ndarray) -> np.ndarray:
        p = points[:, None, :]
        return np.any(np.all((p > lows) & (p < highs), axis=2), axis=1)

    return solid


def union_of_closed_boxes(boxes: list[Box]) -> trimesh.Trimesh:
    return trimesh.util.concatenate([box_mesh(b) for b in boxes])


def cabinet() -> SignCase:
    """Four deep cubbies open at the front, every panel a closed box (like a real 22-part shelf unit)."""
    t = 0.05
    boxes = [
        ((-0.6, -0.7, -0.5), (-0.6 + t, 0.7, 0.5)),
        ((0.6 - t, -0.7, -0.5), (0.6, 0.7, 0.5)),  # sides
        ((-0.55, 0.7 - t, -0.5), (0.55, 0.7, 0.5)),
        ((-0.55, -0.7, -0.5), (0.55, -0.7 + t, 0.5)),  # top, bottom
        ((-0.55, -t / 2, -0.45), (0.55, t / 2, 0.5)),  # shelf
        ((-t / 2, -0.65, -0.45), (t / 2, 0.65, 0.5)),  # divider, crossing the shelf
        ((-0.55, -0.65, -0.5), (0.55, 0.65, -0.45)),  # back
    ]
    return SignCase(
        "cabinet with open cubbies",
        union_of_closed_boxes(boxes),
        in_boxes(boxes),
        "the panels are inside; the cubbies are outside however deep",
    )


def drawer_table() -> SignCase:
    """A table whose drawer is a box of closed panels under the top, open at the front."""
    boxes = [((-0.6, 0.375, -0.4), (0.6, 0.425, 0.4))]  # top
    boxes += [((x - 0.03, -0.4, z - 0.03), (x + 0.03, 0.375, z + 0.03)) for x in (-0.55, 0.55) for z in (-0.35, 0.35)]
    boxes += [
        ((-0.3, 0.24, -0.3), (0.3, 0.26, 0.3)),  # drawer bottom
        ((-0.3, 0.26, -0.3), (-0.28, 0.375, 0.3)),
        ((0.28, 0.26, -0.3), (0.3, 0.375, 0.3)),  # drawer sides
        ((-0.28, 0.26, -0.3), (0.28, 0.375, -0.28)),  # drawer back
    ]
    return SignCase(
        "table with a drawer open at the front",
        union_of_closed_boxes(boxes),
        in_boxes(boxes),
        "top, legs and drawer panels are inside; the drawer's shallow cavity is outside",
    )


def _box_surface_with_holes(box: Box, holes: list[Box], subdivisions: int = 3) -> trimesh.Trimesh:
    """The box's surface (one sheet, no thickness) with the faces whose centroid lies in a hole box removed."""
    mesh = box_mesh(box)
    for _ in range(subdivisions):
        mesh = mesh.subdivide()
    cut = in_boxes(holes)(mesh.triangles_center)
    return trimesh.Trimesh(mesh.vertices, mesh.faces[~cut], process=False)


def open_shell_chair() -> SignCase:
    """Seat and back each one double-walled surface (outer wall, inner wall, rim) with five holes in the rim."""
    seat = ((-0.4, -0.05, -0.4), (0.4, 0.05, 0.4))
    back = ((-0.4, 0.06, -0.45), (0.4, 0.86, -0.35))
    seat_holes = [((x - 0.06, -0.1, 0.39), (x + 0.06, 0.1, 0.5)) for x in (-0.25, 0.0, 0.25)]
    seat_holes += [((-0.5, -0.1, -0.06), (-0.39, 0.1, 0.06)), ((0.39, -0.1, -0.06), (0.5, 0.1, 0.06))]
    back_holes = [((x - 0.06, 0.855, -0.5), (x + 0.06, 0.9, -0.3)) for x in (-0.25, 0.0, 0.25)]
    back_holes += [((-0.5, y - 0.06, -0.5), (-0.395, y + 0.06, -0.3)) for y in (0.3, 0.6)]
    mesh = trimesh.util.concatenate(
        [_box_surface_with_holes(seat, seat_holes), _box_surface_with_holes(back, back_holes)]
    )
    return SignCase(
        "open double-walled shell",
        mesh,
        in_boxes([]),
        "nothing is inside: the space between the walls is reached through the rim holes, so it is "
        "outside, as a flood-filled voxelisation leaves it (hollow)",
    )


def sheet_chair() -> SignCase:
    """Seat and back each a single sheet meeting at an edge, on four closed legs: sheets enclose nothing."""
    seat = trimesh.Trimesh([[-0.4, 0, -0.4], [0.4, 0, -0.4], [0.4, 0, 0.4], [-0.4, 0, 0.4]], [[0, 2, 1], [0, 3, 2]])
    back = trimesh.Trimesh(
        [[-0.4, 0, -0.4], [0.4, 0, -0.4], [0.4, 0.8, -0.4], [-0.4, 0.8, -0.4]], [[0, 1, 2], [0, 2, 3]]
    )
    legs = [((x - 0.04, -0.8, z - 0.04), (x + 0.04, -0.01, z + 0.04)) for x in (-0.33, 0.33) for z in (-0.33, 0.33)]
    mesh = trimesh.util.concatenate([seat, back, union_of_closed_boxes(legs)])
    return SignCase(
        "chair of bare sheets on closed legs",
        mesh,
        in_boxes(legs),
        "only the legs are inside; the wedge between seat and back sheets is outside",
    )


def broken_soup(seed: int = 0) -> SignCase:
    """Three boxes: randomly flipped faces, one inside-out, duplicated and inner faces, a non-manifold edge and fin."""
    rng = np.random.default_rng(seed)
    a, b, c = (
        ((-0.5, -0.5, -0.25), (0.0, 0.0, 0.25)),
        ((0.0, 0.0, -0.25), (0.5, 0.5, 0.25)),
        ((-0.3, -0.7, -0.1), (-0.1, -0.3, 0.1)),
    )
    box_a = box_mesh(a).subdivide()
    faces_a = box_a.faces.copy()
    flip = rng.random(len(faces_a)) < 0.5
    faces_a[flip] = faces_a[flip][:, ::-1]
    parts = [
        trimesh.Trimesh(box_a.vertices, faces_a, process=False),
        trimesh.Trimesh(box_mesh(b).vertices, box_mesh(b).faces[:, ::-1], process=False),  # inside-out, shares A's edge
        box_mesh(c),  # overlaps A
        trimesh.Trimesh(box_a.vertices, box_a.faces[:6][:, ::-1], process=False),  # faces stored twice, once per side
        trimesh.Trimesh([[0.5, 0.5, -0.25], [0.5, 0.5, 0.25], [0.8, 0.8, 0.0]], [[0, 1, 2]], process=False),  # fin
        trimesh.Trimesh(
            [[-0.4, -0.4, 0.0], [-0.1, -0.4, 0.0], [-0.25, -0.1, 0.0]], [[0, 1, 2]], process=False
        ),  # inner
    ]
    return SignCase(
        "flipped and non-manifold soup",
        trimesh.util.concatenate(parts),
        in_boxes([a, b, c]),
        "the union of the three boxes is inside; fin and inner face change nothing",
    )


def sieve_sphere(seed: int = 0) -> SignCase:
    """A sphere of radius 0.8 with 6% of its faces missing at random."""
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.8)
    kept = np.random.default_rng(seed).random(len(sphere.faces)) > 0.06
    return SignCase(
        "sphere with 6% of faces missing",
        trimesh.Trimesh(sphere.vertices, sphere.faces[kept], process=False),
        in_boxes([]),
        "nothing is inside: the ball is reached through the missing faces (hollow voxels)",
    )


def open_box() -> SignCase:
    """A single-sided box surface with one whole side missing: a block without its lid, or a container?

    Not a known-answer case: the point of it is that no test of the mesh can know.
    """
    mesh = _box_surface_with_holes(((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5)), [((-1, 0.45, -1), (1, 1, 1))], subdivisions=2)
    return SignCase(
        "box with one side missing",
        mesh,
        None,
        "cannot be told: a solid block missing its top, or an open container; the sign report flags it",
    )


def sheet() -> SignCase:
    """One square sheet: it encloses nothing."""
    mesh = trimesh.Trimesh([[-0.5, 0, -0.5], [0.5, 0, -0.5], [0.5, 0, 0.5], [-0.5, 0, 0.5]], [[0, 1, 2], [0, 2, 3]])
    return SignCase(
        "single sheet", mesh, lambda p: np.zeros(len(p), bool), "nothing is inside; rejected as enclosing no volume"
    )


def _legs(top: float, half_x: float, half_z: float, width: float = 0.06) -> list[Box]:
    w = width / 2
    return [((x - w, -0.8, z - w), (x + w, top, z + w)) for x in (-half_x, half_x) for z in (-half_z, half_z)]


def sealed_box_table() -> SignCase:
    """A tabletop built as a box of six closed thin plates touching at the edges, on four closed legs.

    The hollow inside the box has winding number 0 and no straight ray leaves it, yet nothing from
    outside reaches it: the official voxels fill it.
    """
    x0, x1, y0, y1, z0, z1, t = -0.6, 0.6, 0.3, 0.5, -0.4, 0.4, 0.02
    plates = [
        ((x0, y1 - t, z0), (x1, y1, z1)),  # top
        ((x0, y0, z0), (x1, y0 + t, z1)),  # bottom
        ((x0, y0 + t, z0), (x0 + t, y1 - t, z1)),
        ((x1 - t, y0 + t, z0), (x1, y1 - t, z1)),  # left, right
        ((x0 + t, y0 + t, z0), (x1 - t, y1 - t, z0 + t)),
        ((x0 + t, y0 + t, z1 - t), (x1 - t, y1 - t, z1)),  # back, front
    ]
    legs = _legs(y0, 0.55, 0.35)
    return SignCase(
        "tabletop box of six closed plates (sealed hollow)",
        union_of_closed_boxes(plates + legs),
        in_boxes([((x0, y0, z0), (x1, y1, z1))] + legs),
        "the plates, legs and the sealed hollow between the plates are inside",
    )


def doubled_soup_chair(seed: int = 0) -> SignCase:
    """A chair of closed boxes stored as a triangle soup: every face twice, 1e-4 apart, each its own component."""
    rng = np.random.default_rng(seed)
    boxes = [((-0.4, -0.05, -0.4), (0.4, 0.05, 0.4)), ((-0.4, 0.05, -0.4), (0.4, 0.85, -0.32))] + _legs(
        -0.05, 0.34, 0.34
    )
    parts = []
    for box in boxes:
        mesh = box_mesh(box).subdivide().subdivide().subdivide()
        triangles = mesh.triangles
        copies = [triangles, triangles[:, ::-1] - 1e-4 * mesh.face_normals[:, None, :]]  # the twin faces inward
        for copy in copies:
            flip = rng.random(len(copy)) < 0.5
            copy = np.where(flip[:, None, None], copy[:, ::-1], copy)
            parts.append(copy)
    triangles = np.concatenate(parts)
    mesh = trimesh.Trimesh(triangles.reshape(-1, 3), np.arange(3 * len(triangles)).reshape(-1, 3), process=False)
    return SignCase(
        "chair with every face stored twice (triangle soup)",
        mesh,
        in_boxes(boxes),
        "the boxes are inside; the space between them is outside",
    )


def open_seat_chair() -> SignCase:
    """A chair whose seat and back are one single-sided surface left open at the back, on closed legs.

    Like a model whose back was never modelled: a flood-filled voxelisation enters through the
    opening and leaves the seat a hollow shell.
    """
    seat = ((-0.4, -0.05, -0.4), (0.4, 0.05, 0.4))
    opening = [((-0.5, -0.1, -0.5), (0.5, 0.1, -0.399))]
    legs = _legs(-0.05, 0.34, 0.34)
    mesh = trimesh.util.concatenate([_box_surface_with_holes(seat, opening), union_of_closed_boxes(legs)])
    return SignCase(
        "seat surface open at the back (hollow voxels)",
        mesh,
        in_boxes(legs),
        "only the legs are inside; the seat's inside is reached through the open back",
    )


KNOWN_ANSWER_CASES = (
    cabinet,
    drawer_table,
    open_shell_chair,
    sheet_chair,
    broken_soup,
    sieve_sphere,
    sealed_box_table,
    doubled_soup_chair,
    open_seat_chair,
)
