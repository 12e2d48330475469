"""Everything cached for one shape (style record, mesh, SDF samples, renders): check, then make what is missing.

Runs in worker processes, so it takes a picklable `ShapeJob` and returns a `ShapeResult`
listing what it regenerated and why; the parent turns corrupt files into warnings.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np
import trimesh
from PIL import Image

from ushape import atomic
from ushape.data import integrity
from ushape.data.cameras import format_metadata, metadata_to_cameras, parse_metadata, sample_r2n2_views
from ushape.data.layout import WorldIndex
from ushape.data.rendering import render_views
from ushape.data.sampling import sample_sdf
from ushape.data.shading import part_colour_fn

ShapeFactory = Callable[[str, int], Any]  # (category, seed) -> Shape

# Separate random streams per artifact: regenerating one never shifts another's randomness.
SDF_STREAM = 1
VIEWS_STREAM = 2
ARTIFACTS = ("shape", "mesh", "sdf", "renders")


@dataclass(frozen=True)
class ShapeJob:
    index: WorldIndex
    split: str
    position: int
    seed: int
    shape_id: str
    factory: ShapeFactory


@dataclass
class ShapeResult:
    shape_id: str
    made: list[str] = field(default_factory=list)  # artifacts (re)generated
    corrupt: list[tuple[str, str]] = field(default_factory=list)  # (path, reason)


def artifact_problems(index: WorldIndex, shape_id: str) -> dict[str, tuple[str, str]]:
    """Artifacts of one shape needing (re)generation -> (offending path, reason)."""
    cfg = index.config
    n_views, size = int(cfg["n_views"]), int(cfg["image_size"])
    hw = (size, size)
    checks: dict[str, list[tuple[Any, Callable[[], Optional[str]]]]] = {
        "shape": [(index.shape_path(shape_id), lambda: integrity.check_json(index.shape_path(shape_id)))],
        "mesh": [(index.mesh_path(shape_id), lambda: integrity.check_ply(index.mesh_path(shape_id)))],
        "sdf": [
            (
                index.sdf_path(shape_id),
                lambda: integrity.check_npz(
                    index.sdf_path(shape_id), {"pos": (None, 4), "neg": (None, 4)}, {"pos": "float32", "neg": "float32"}
                ),
            )
        ],
        "renders": [
            (
                index.metadata_path(shape_id),
                lambda: integrity.check_text_rows(index.metadata_path(shape_id), n_views, 5),
            ),
            (
                index.views_path(shape_id),
                lambda: integrity.check_npz(
                    index.views_path(shape_id),
                    {
                        "K": (n_views, 3, 3),
                        "world_to_cam": (n_views, 4, 4),
                        "masks": (n_views, *hw),
                        "depth": (n_views, *hw),
                    },
                    {"masks": "bool", "depth": "float32"},
                ),
            ),
        ]
        + [(p, lambda p=p: integrity.check_png(p, hw)) for p in index.image_paths(shape_id)],
    }
    problems = {}
    for artifact, artifact_checks in checks.items():
        for path, check in artifact_checks:
            reason = check()
            if reason is not None:
                problems[artifact] = (str(path), reason)
                break
    return problems


def build_shape(job: ShapeJob) -> ShapeResult:
    """Check one shape's cached files and regenerate the missing or corrupt ones."""
    index, result = job.index, ShapeResult(job.shape_id)
    problems = artifact_problems(index, job.shape_id)
    if not problems:
        return result
    result.corrupt = [pr for pr in problems.values() if pr[1] != integrity.MISSING]
    shape = job.factory(index.category, job.seed)
    if shape.shape_id != job.shape_id:
        raise RuntimeError(
            f"shape factory gave id {shape.shape_id!r} for seed {job.seed}, but the split lists "
            f"{job.shape_id!r}: the generator changed; bump GENERATOR_VERSION in ushape.data.world"
        )
    if "shape" in problems:
        atomic.write_json(index.shape_path(job.shape_id), _shape_record(shape, job))
    if "mesh" in problems:
        mesh = shape.mesh(resolution=int(index.config["mesh_resolution"]))
        atomic.write_bytes(index.mesh_path(job.shape_id), trimesh.exchange.ply.export_ply(mesh, encoding="binary"))
    if "sdf" in problems or "renders" in problems:
        mesh = trimesh.load(index.mesh_path(job.shape_id), process=False, force="mesh")
    if "sdf" in problems:
        rng = np.random.default_rng(np.random.SeedSequence(job.seed, spawn_key=(SDF_STREAM,)))
        samples = sample_sdf(shape, mesh, int(index.config["samples_per_shape"]), rng)
        atomic.save_npz(index.sdf_path(job.shape_id), **samples)
    if "renders" in problems:
        write_renders(index, job, shape, mesh)
    result.made = [a for a in ARTIFACTS if a in problems]
    return result


def r2n2_frame(mesh: trimesh.Trimesh) -> tuple[np.ndarray, float]:
    """(bounding-box centre [3], scale) mapping the mesh into R2N2's unit-diagonal frame."""
    lo, hi = mesh.bounds
    return (lo + hi) / 2.0, 1.0 / float(np.linalg.norm(hi - lo))


def write_renders(index: WorldIndex, job: ShapeJob, shape: Any, mesh: trimesh.Trimesh) -> None:
    """Render the shape's R2N2-protocol views and write PNGs, metadata and views.npz."""
    n_views, size = int(index.config["n_views"]), int(index.config["image_size"])
    rng = np.random.default_rng(np.random.SeedSequence(job.seed, spawn_key=(VIEWS_STREAM,)))
    text = format_metadata(sample_r2n2_views(n_views, rng))
    # Cameras come from the rows as written, so reloading the metadata reproduces them exactly.
    rows = parse_metadata(text)
    centre, scale = r2n2_frame(mesh)
    Ks, world_to_cams = metadata_to_cameras(rows, size, r2n2_centre=centre, r2n2_scale=scale)
    views = render_views(mesh, Ks, world_to_cams, size, part_colour_fn(shape))
    for view, rgba in enumerate(views["rgba"]):
        buffer = io.BytesIO()
        Image.fromarray(rgba, mode="RGBA").save(buffer, format="PNG")
        atomic.write_bytes(index.image_path(job.shape_id, view), buffer.getvalue())
    atomic.write_text(index.metadata_path(job.shape_id), text)
    atomic.save_npz(
        index.views_path(job.shape_id),
        K=Ks.astype(np.float32),
        world_to_cam=world_to_cams.astype(np.float32),
        masks=views["mask"],
        depth=views["depth"].astype(np.float32),
        r2n2_centre=centre.astype(np.float32),
        r2n2_scale=np.float32(scale),
    )


def _shape_record(shape: Any, job: ShapeJob) -> dict[str, Any]:
    return {
        "shape_id": shape.shape_id,
        "category": shape.category,
        "split": job.split,
        "index": job.position,
        "seed": job.seed,
        "style": _jsonable(shape.style),
        "part_names": _jsonable(list(getattr(shape, "part_names", []))),
        "part_colours": _jsonable(np.asarray(shape.part_colours())),
    }


def _jsonable(value: Any) -> Any:
    """Plain JSON types from numpy scalars/arrays nested in dicts, lists and tuples."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value
