"""Signed distance of real CAD meshes (ShapeNet, Pix3D), in the mesh's own frame.

Real meshes are triangle soups: open, with inner faces, flipped or inconsistent normals and
duplicated geometry. So the two halves of the SDF are computed separately:

- Magnitude: exact point-to-triangle distance (libigl's AABB tree).
- Sign: `ushape.data.real.mesh_signs`: inside when the point cannot be reached from outside
  without crossing a face, the convention of ShapeNet's and Pix3D's official voxels, at 256
  voxels along the mesh's longest side. Sealed hollows are inside, open compartments and
  open models' insides outside; flipped, duplicated and non-manifold faces change nothing.
- Normalisation: DeepSDF's (bounding-box centre to the origin, farthest vertex at radius
  1/1.03), the same frame the synthetic shapes use.

Anything that makes a mesh unusable raises `MeshProcessingError`, which dataset builders
catch, log and skip, so one bad model never stops a whole preprocessing run. A mesh whose
encloses no volume is one of them; every accepted mesh comes with a `SignReport` saying how
much of its sign depends on the method or the resolution, which the builders write into the
shape's record.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Optional

import igl
import numpy as np
import trimesh

from ushape.data.real.mesh_signs import MeshSigns, SignTally
from ushape.data.sampling import sample_points, split_by_sign
from ushape.data.shading import DEFAULT_ALBEDO

UNIT_SPHERE_BUFFER = 1.03  # DeepSDF: farthest vertex at 1/1.03 leaves room for the decoder's band
SIGN_METHOD = "unreachable from outside: surface voxels at 256^3, exterior flood fill, rays near the surface"


class MeshProcessingError(ValueError):
    """A model that cannot become SDF samples (unreadable, empty, degenerate, or with no inside)."""


def load_mesh(path: str | Path) -> trimesh.Trimesh:
    """One Trimesh from a model file (all parts concatenated), with per-face colours when it has any."""
    path = Path(path)
    if not path.is_file():
        raise MeshProcessingError(f"model file {path} does not exist")
    # ShapeNet v2's MTL files name textures as ../images/*.jpg, outside the OBJ's folder, which
    # trimesh refuses to read by default; the dataset is the user's own, so allow it.
    resolver = trimesh.resolvers.FilePathResolver(path.parent, allow_anywhere=True)
    try:
        scene = trimesh.load_scene(path, resolver=resolver)
    except Exception as err:  # noqa: BLE001  (trimesh's loaders raise many exception types)
        raise MeshProcessingError(f"cannot read {path}: {type(err).__name__}: {err}") from err
    parts = [g for g in scene.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    if not parts:
        raise MeshProcessingError(f"{path} holds no triangles")
    colours = [_face_colours(p) for p in parts]
    vertices, faces, offset = [], [], 0
    for part in parts:
        vertices.append(np.asarray(part.vertices, np.float64))
        faces.append(np.asarray(part.faces) + offset)
        offset += len(part.vertices)
    mesh = trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False)
    if any(c is not None for c in colours):
        # Parts without a material get the renderer's neutral grey rather than dropping all colour.
        grey = np.array([*np.round(np.asarray(DEFAULT_ALBEDO) * 255), 255], np.uint8)
        colours = [np.tile(grey, (len(p.faces), 1)) if c is None else c for c, p in zip(colours, parts)]
        mesh.visual = trimesh.visual.ColorVisuals(mesh, face_colors=np.concatenate(colours))
    check_mesh(mesh, str(path))
    return mesh


def _face_colours(part: trimesh.Trimesh) -> Optional[np.ndarray]:
    """RGBA uint8 [F,4]: texture sampled at each face's UV centroid, else the material colour."""
    visual = part.visual
    if getattr(visual, "kind", None) == "face":
        return np.asarray(visual.face_colors, np.uint8)
    material = getattr(visual, "material", None)
    if material is None:
        return None
    image, uv = getattr(material, "image", None), getattr(visual, "uv", None)
    if image is not None and uv is not None and len(uv) == len(part.vertices):
        centroid_uv = np.asarray(uv)[part.faces].mean(axis=1)
        return trimesh.visual.color.uv_to_color(centroid_uv, image)
    main = getattr(material, "main_color", None)
    if main is None:
        return None
    return np.tile(np.asarray(main, np.uint8), (len(part.faces), 1))


def check_mesh(mesh: trimesh.Trimesh, name: str = "mesh") -> None:
    """Raise MeshProcessingError unless the mesh has finite vertices and non-degenerate area and extent."""
    if len(mesh.faces) == 0:
        raise MeshProcessingError(f"{name} has no faces")
    if not np.all(np.isfinite(mesh.vertices)):
        raise MeshProcessingError(f"{name} has NaN or infinite vertex coordinates")
    if not np.all((mesh.faces >= 0) & (mesh.faces < len(mesh.vertices))):
        raise MeshProcessingError(f"{name} has faces indexing missing vertices")
    extents = np.ptp(mesh.vertices[np.unique(mesh.faces)], axis=0)
    if mesh.area <= 0 or np.sum(extents > 1e-9 * max(extents.max(), 1e-30)) < 2:
        raise MeshProcessingError(f"{name} is degenerate (zero area, or all faces on a line or point)")


def unit_sphere_normalisation(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """DeepSDF (centre [3], scale) with p_normalised = (p - centre) * scale, for vertices [N,3]."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = (lo + hi) / 2.0
    radius = float(np.linalg.norm(vertices - centre, axis=1).max())
    if not np.isfinite(radius) or radius <= 0:
        raise MeshProcessingError(f"cannot normalise a mesh of radius {radius}")
    return centre, 1.0 / (radius * UNIT_SPHERE_BUFFER)


def normalise_mesh(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray, float]:
    """(copy of the mesh in DeepSDF's unit-sphere frame, centre [3], scale); only used vertices count."""
    check_mesh(mesh)
    centre, scale = unit_sphere_normalisation(mesh.vertices[np.unique(mesh.faces)])
    normalised = mesh.copy()
    normalised.vertices = (mesh.vertices - centre) * scale
    return normalised, centre, scale


class MeshSdf:
    """Signed distance [N] of points [N,3] to a real mesh: exact magnitude, reachability sign (< 0 inside)."""

    def __init__(self, mesh: trimesh.Trimesh, seed: int = 0, **sign_options) -> None:
        check_mesh(mesh)
        self.signs = MeshSigns(mesh, seed=seed, **sign_options)

    def distance_and_closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance [N] from points [N,3] to the nearest triangle, that triangle's closest point [N,3])."""
        points = np.ascontiguousarray(points, np.float64)
        squared, _, closest = igl.point_mesh_squared_distance(points, self.signs.vertices, self.signs.faces)
        return np.sqrt(squared), closest

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Distance [N] from points [N,3] to the nearest triangle."""
        return self.distance_and_closest(points)[0]

    def inside(self, points: np.ndarray) -> np.ndarray:
        """Bool [N]: the point is inside the mesh (see ushape.data.real.mesh_signs)."""
        return self.signs.inside(np.asarray(points, np.float64), *self.distance_and_closest(points))

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """Signed distance [N] of points [N,3]; negative inside."""
        points = np.asarray(points, np.float64)
        distance, closest = self.distance_and_closest(points)
        return np.where(self.signs.inside(points, distance, closest), -distance, distance)


@dataclass(frozen=True)
class SignReport:
    """How one mesh's SDF signs were decided, for filtering a dataset by how sure they are."""

    method: str
    samples: int
    confidence: float  # share of far samples whose sign depends on neither method nor resolution (lower bound)
    resolution_agreement: float  # far samples with the same sign on the check grid (mesh_signs.CHECK_RESOLUTION)
    winding_agreement: float  # far samples with the same sign by the winding number, |w| > 1/2
    inside: float  # share of samples inside
    near: float  # share nearer than a voxel diagonal to the mesh, decided by rays
    enclosed: float  # share of near samples no ray got out from (called inside)
    resolution: int
    check_resolution: int

    @classmethod
    def of(cls, signs: MeshSigns) -> "SignReport":
        tally: SignTally = signs.tally
        return cls(
            method=SIGN_METHOD,
            samples=tally.points,
            confidence=tally.confidence,
            resolution_agreement=tally.resolution_agreement,
            winding_agreement=tally.winding_agreement,
            inside=tally.share(tally.inside),
            near=tally.share(tally.near),
            enclosed=tally.share(tally.enclosed),
            resolution=signs.grid.resolution,
            check_resolution=signs.check_grid.resolution,
        )

    def as_dict(self) -> dict:
        return asdict(self)


def previous_signs(record_path: Path) -> Optional[dict]:
    """The `sdf_signs` a shape record already holds (None if it has none or is unreadable), for records rewritten
    without resampling."""
    try:
        return json.loads(Path(record_path).read_text()).get("sdf_signs")
    except (OSError, ValueError, AttributeError):
        return None


def sample_mesh_sdf(
    mesh: trimesh.Trimesh,
    n_points: int,
    rng: np.random.Generator,
    min_inside_fraction: float = 0.002,
    min_confidence: float = 0.0,
    **sign_options,
) -> tuple[dict[str, np.ndarray], SignReport]:
    """DeepSDF samples {"pos": [P,4], "neg": [Q,4]} of a normalised real mesh, and how sure their signs are.

    Raises MeshProcessingError when the mesh encloses (almost) no volume (nothing is unreachable from
    outside: sheets, open models) or when the sign confidence is under min_confidence (by default
    every mesh is kept and its report says how sure its signs are). `sign_options` go to MeshSigns.
    """
    sdf = MeshSdf(mesh, seed=int(rng.integers(2**31)), **sign_options)
    points = sample_points(mesh, n_points, rng)
    samples = split_by_sign(points, sdf.sdf(points))
    report = SignReport.of(sdf.signs)
    if report.confidence < min_confidence:
        raise MeshProcessingError(
            f"signs depend on the method: only {report.confidence:.0%} of far SDF samples keep their sign at "
            f"{report.check_resolution}^3 and by the winding number (need {min_confidence:.0%}; resolution agreement "
            f"{report.resolution_agreement:.1%}, winding agreement {report.winding_agreement:.1%}); the mesh is open "
            "or sealed only by gaps near the voxel size"
        )
    if report.inside < min_inside_fraction:
        raise MeshProcessingError(
            f"only {report.inside:.2%} of SDF samples are inside (need {min_inside_fraction:.2%}): the mesh "
            "encloses no volume sealed from outside (single-sided sheets or an open model), so the decoder would learn "
            "no surface"
        )
    return samples, report
