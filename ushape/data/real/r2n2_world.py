"""The 3D-R2N2 bundle (ShapeNetVox32, optionally ShapeNetRendering) preprocessed into the world layout.

    <cache_root>/r2n2/<synset>-<hash12>/   config.json, splits/, meshes/, sdf/, renders/, shapes/, skipped.json

For researchers who have only R2N2's download, not ShapeNetCore's meshes. Per model: the 32^3 voxels
become a closed surface (`ushape.data.real.r2n2_voxels`) in R2N2's frame, normalised to DeepSDF's
unit sphere like every other world; SDF samples are exact distances to that surface with its own
sign; views are R2N2's renders and cameras when `renderings_root` holds the model, otherwise our own
R2N2-protocol renders of the surface. Splits are the ShapeNet world's (a split file, or a hash of the
ids), capped per split by n_train / n_val / n_test (the first ids by hash, so a larger cap keeps the
smaller one's shapes).

Small on disk: a model's information is 32^3 bits, so the world stores fewer samples than a mesh
world (samples_per_shape) and compresses its arrays (`save_npz_compressed`); docs/r2n2.md has the
sizes. A model that cannot be used (voxel file missing or corrupt, grid empty, renders without
voxels, incomplete renders) is logged and listed in skipped.json with the reason, never stopping the
build. Every file is written atomically and valid files are kept, so an interrupted build resumes.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Optional, Sequence

import numpy as np
import trimesh

from ushape import atomic
from ushape.data.cameras import metadata_to_cameras, parse_metadata
from ushape.data.jobs import run_jobs
from ushape.data.layout import SPLITS, WorldIndex
from ushape.data.real import r2n2_voxels, shapenet, shapenet_rendering
from ushape.data.real.mesh_sdf import MeshProcessingError, normalise_mesh
from ushape.data.real.world_build import (
    checked_renderings_root,
    json_differs,
    split_fingerprint,
    store_views,
    view_source,
    write_splits,
)
from ushape.data.rendering import render_views
from ushape.data.sampling import sample_points, split_by_sign
from ushape.data.shape_artifacts import artifact_problems
from ushape.errors import InputError, MissingInputError
from ushape.workspace import CONFIG_FILE, SKIPPED_FILE

log = logging.getLogger(__name__)

PREPROCESS_VERSION = 1

SDF_STREAM = 1  # a model's SDF samples' random stream (its views': world_build.VIEWS_STREAM)
MIN_INSIDE_FRACTION = 0.002  # as the mesh worlds: a surface enclosing (almost) nothing teaches no shape
# Stored values are rounded to multiples of 2^-bits (still float32), which deflate then packs: a voxel
# is ~0.045 wide in DeepSDF's frame, so 2^-12 (2.4e-4) for sample positions, 2^-14 for their SDF and
# 2^-10 (1e-3, of depths ~1.5-4) for depth maps lose nothing the voxels hold, and halve the files.
POSITION_BITS, SDF_BITS, DEPTH_BITS = 12, 14, 10
# deflate level 3: twice as fast as numpy's 6 for 10% more bytes (the build's time goes to
# compression and rendering about equally).
NPZ_LEVEL = 3


@dataclass(frozen=True)
class VoxelJob:
    index: WorldIndex  # root and config only: jobs stay small however many models the world has
    model_id: str
    split: str
    synset: str
    voxel_file: str
    renderings_root: Optional[str]  # None, or a root that holds this model's renders
    seed: int


class R2N2World:
    """Builds (once) and caches one category of the 3D-R2N2 bundle as a world; `build()` returns its index."""

    # Config keys naming folders it reads: checked to exist before a run starts (training.validation).
    INPUT_FOLDERS = ("voxels_root", "renderings_root")

    def __init__(
        self,
        category: str,
        voxels_root: str,
        cache_root: str,
        renderings_root: Optional[str] = None,
        split_file: shapenet.SplitSource = None,
        samples_per_shape: int = 32_768,
        n_views: int = 24,
        image_size: int = 137,
        seed: int = 0,
        n_train: Optional[int] = None,
        n_val: Optional[int] = None,
        n_test: Optional[int] = None,
        num_workers: int = 0,
        split_fractions: Sequence[float] = shapenet.DEFAULT_FRACTIONS,
    ) -> None:
        for name, value in (("samples_per_shape", samples_per_shape), ("n_views", n_views), ("image_size", image_size)):
            if int(value) < 1:
                raise ValueError(f"{name} must be positive, got {value}")
        caps = {"train": n_train, "val": n_val, "test": n_test}
        if any(c is not None and int(c) < 0 for c in caps.values()) or (n_train is not None and int(n_train) < 1):
            raise ValueError(f"n_train must be >= 1 and n_val, n_test >= 0 (or null for all), got {caps}")
        self.synset = shapenet.synset_id(category)
        self.voxels_root = Path(voxels_root).expanduser().resolve()
        if not (self.voxels_root / self.synset).is_dir():
            raise MissingInputError(
                f"voxels_root {self.voxels_root} has no folder {self.synset}. Expected {r2n2_voxels.EXPECTED_LAYOUT}"
            )
        self.renderings_root = checked_renderings_root(renderings_root, self.synset, n_views)
        self.cache_root = Path(cache_root).expanduser()
        self.split_file = split_file
        self.num_workers = int(num_workers)
        self.config: dict[str, Any] = {
            "dataset": "r2n2",
            "category": str(category),
            "synset": self.synset,
            "voxels_root": str(self.voxels_root),
            "renderings_root": self.renderings_root,
            "split": split_fingerprint(split_file),
            "split_fractions": [float(f) for f in split_fractions],
            "caps": {k: None if v is None else int(v) for k, v in caps.items()},
            "samples_per_shape": int(samples_per_shape),
            "n_views": int(n_views),
            "image_size": int(image_size),
            "seed": int(seed),
            "surface": {"sigma": r2n2_voxels.SMOOTHING_SIGMA, "level": r2n2_voxels.ISO_LEVEL},
            "preprocess_version": PREPROCESS_VERSION,
        }

    @property
    def directory(self) -> Path:
        digest = hashlib.sha256(json.dumps(self.config, sort_keys=True).encode()).hexdigest()[:12]
        return self.cache_root / "r2n2" / f"{self.synset}-{digest}"

    def model_ids(self) -> list[str]:
        """Sorted ids of every model folder under voxels_root/<synset> (with or without its binvox)."""
        return sorted(d.name for d in (self.voxels_root / self.synset).iterdir() if d.is_dir())

    def rendered_ids(self) -> set[str]:
        if not self.renderings_root:
            return set()
        folder = Path(self.renderings_root) / self.synset
        return {d.name for d in folder.iterdir() if (d / shapenet_rendering.RENDERING_DIR).is_dir()}

    def planned_splits(self, ids: Sequence[str]) -> dict[str, list[str]]:
        """Model ids per split before any skipping: split file or hash split, each capped."""
        if self.split_file is None:
            splits = shapenet.hash_split(ids, self.config["split_fractions"])
        else:
            splits = shapenet.read_split_source(self.split_file, self.synset)
        capped = {}
        for split, members in splits.items():
            cap, unique = self.config["caps"][split], list(dict.fromkeys(members))
            # A cap keeps the first ids by hash; uncapped, a split file's order is kept.
            capped[split] = unique if cap is None else sorted(unique, key=lambda i: (shapenet.id_hash(i), i))[:cap]
        return capped

    def build(self) -> WorldIndex:
        """Preprocess whatever is missing (idempotent) and return the world's index."""
        start = time.perf_counter()
        root = self.directory
        if json_differs(root / CONFIG_FILE, self.config):
            atomic.write_json(root / CONFIG_FILE, self.config)
        removed = atomic.remove_temp_files(root)
        if removed:
            log.info("removed %d temporary files of an interrupted build from %s", len(removed), root)
        ids = self.model_ids()
        if not ids:
            raise FileNotFoundError(
                f"{self.voxels_root / self.synset} holds no model folders. {r2n2_voxels.EXPECTED_LAYOUT}"
            )
        planned = self.planned_splits(ids)
        # Skips are decided afresh each build (skipped.json only reports them): a model skipped before is tried
        # again, so a voxel file mended or replaced since is used; one still bad costs a read and is listed again.
        skipped: dict[str, str] = {}
        rendered = self.rendered_ids()
        known = set(ids)
        for mid in sorted(rendered - known):
            skipped.setdefault(mid, f"has renders under {self.renderings_root} but no voxels under {self.voxels_root}")
        for mid in sorted({m for members in planned.values() for m in members} - known):
            skipped.setdefault(mid, f"listed in the split but {self.voxels_root / self.synset / mid} is missing")
        light = WorldIndex(root=root, category=self.config["category"], splits={}, config=self.config)
        jobs = {
            mid: self._job(light, split, mid, mid in rendered)
            for split in SPLITS
            for mid in planned[split]
            if mid not in skipped
        }
        for model_id, reason in self._run(list(jobs.values())):
            if reason is not None:
                log.warning("skipping R2N2 model %s: %s", model_id, reason)
                skipped[model_id] = reason
                atomic.write_json(root / SKIPPED_FILE, skipped)  # as they come: an interrupted build keeps them
        write_splits(light, planned, skipped, f"{self.synset} under {self.voxels_root}", "the voxel layout")
        check_split_sizes(planned, skipped, self.config["caps"], root / SKIPPED_FILE)
        log.info(
            "R2N2 %s world %s ready in %.1fs (%d models, %d skipped)",
            self.synset,
            root,
            time.perf_counter() - start,
            len(jobs),
            len(skipped),
        )
        return WorldIndex.load(root)

    def _job(self, index: WorldIndex, split: str, model_id: str, has_renders: bool) -> VoxelJob:
        voxel_file = r2n2_voxels.voxel_path(self.voxels_root, self.synset, model_id)
        seed = int(np.random.SeedSequence([self.config["seed"], shapenet.id_hash(model_id)]).generate_state(1)[0])
        renders = self.renderings_root if has_renders else None
        return VoxelJob(index, model_id, split, self.synset, str(voxel_file), renders, seed)

    def _run(self, jobs: list[VoxelJob]) -> Iterable[tuple[str, Optional[str]]]:
        return run_jobs(process_voxel_model, jobs, self.num_workers, desc=f"R2N2 {self.synset}", unit="model")


def check_split_sizes(
    planned: dict[str, list[str]], skipped: dict[str, str], caps: dict[str, int | None], skipped_file: Path
) -> None:
    """A split that asked for shapes and kept none is an InputError; one that kept fewer than its cap is warned
    about with the shortfall (its models were skipped, or the split has fewer models than the cap)."""
    for split in SPLITS:
        kept = sum(m not in skipped for m in planned[split])
        cap = caps.get(split)
        if cap and kept == 0:
            raise InputError(
                f"the {split} split kept no model of the {cap} asked (data.n_{split}={cap}): "
                f"{len(planned[split])} planned, all skipped or missing (see {skipped_file})"
            )
        if cap and kept < cap:
            dropped, short = len(planned[split]) - kept, cap - len(planned[split])
            why = "; ".join(
                ([f"{dropped} skipped (see {skipped_file})"] if dropped else [])
                + ([f"the split holds only {len(planned[split])} models"] if short > 0 else [])
            )
            log.warning("the %s split has %d of the %d models asked (data.n_%s): %s", split, kept, cap, split, why)


def process_voxel_model(job: VoxelJob) -> tuple[str, Optional[str]]:
    """Make one model's missing artifacts; (model id, None) or (model id, reason it was skipped)."""
    index = job.index
    problems = artifact_problems(index, job.model_id)
    if not problems:
        return job.model_id, None
    try:
        occupancy, side = r2n2_voxels.read_r2n2_voxels(job.voxel_file)
        surface = r2n2_voxels.voxel_surface(occupancy, side)
        mesh, centre, scale = normalise_mesh(surface)
        # R2N2's frame is the voxels' own (origin at the box centre, unit diagonal): in ours it sits here.
        r2n2_centre, r2n2_scale = -centre * scale, 1.0 / scale
        if "mesh" in problems:
            atomic.write_bytes(index.mesh_path(job.model_id), trimesh.exchange.ply.export_ply(mesh, encoding="binary"))
        inside = None
        if "sdf" in problems:
            rng = np.random.default_rng(np.random.SeedSequence(job.seed, spawn_key=(SDF_STREAM,)))
            points = sample_points(mesh, int(index.config["samples_per_shape"]), rng)
            points = quantise(points, POSITION_BITS)
            sdf = quantise(r2n2_voxels.closed_mesh_sdf(mesh, points), SDF_BITS)
            samples = split_by_sign(points, sdf)
            inside = len(samples["neg"]) / len(points)
            if inside < MIN_INSIDE_FRACTION:
                raise MeshProcessingError(f"only {inside:.2%} of SDF samples are inside the voxel surface")
            save_npz_compressed(index.sdf_path(job.model_id), **samples)
        views = "ushape"
        if "renders" in problems:
            views = write_voxel_views(job, mesh, r2n2_centre, r2n2_scale)
        elif job.renderings_root:
            views = "shapenet_rendering"
    except (r2n2_voxels.VoxelError, MeshProcessingError, FileNotFoundError, ValueError) as err:
        return job.model_id, f"{type(err).__name__}: {err}"
    record = {
        "shape_id": job.model_id,
        "category": index.category,
        "synset": job.synset,
        "split": job.split,
        "source": job.voxel_file,
        "voxels": int(occupancy.sum()),
        "voxel_side": side,
        "centre": centre.tolist(),
        "scale": float(scale),
        "views": views,
    }
    if inside is not None:
        record["inside_fraction"] = inside
    atomic.write_json(index.shape_path(job.model_id), record)
    return job.model_id, None


def write_voxel_views(job: VoxelJob, mesh: trimesh.Trimesh, r2n2_centre: np.ndarray, r2n2_scale: float) -> str:
    """PNGs, rendering_metadata.txt and views.npz of one model; returns whose images they are."""
    index, n_views, size = job.index, int(job.index.config["n_views"]), int(job.index.config["image_size"])
    text, rgba = view_source(job.renderings_root, job.synset, job.model_id, job.seed, n_views, size)
    Ks, world_to_cams = metadata_to_cameras(
        parse_metadata(text), size, r2n2_centre=r2n2_centre, r2n2_scale=r2n2_scale, frame="v1"
    )
    ours = render_views(mesh, Ks, world_to_cams, size)
    arrays = {
        "K": Ks.astype(np.float32),
        "world_to_cam": world_to_cams.astype(np.float32),
        "depth": quantise(ours["depth"], DEPTH_BITS),
        "r2n2_centre": np.asarray(r2n2_centre, np.float32),
        "r2n2_scale": np.float32(r2n2_scale),
    }
    store_views(index, job.model_id, text, rgba, ours, arrays, save_npz=save_npz_compressed)
    return "shapenet_rendering" if job.renderings_root else "ushape"


def quantise(values: np.ndarray, bits: int) -> np.ndarray:
    """values [...] rounded to the nearest multiple of 2^-bits, as float32 [...] (exact in float32)."""
    return (np.round(np.asarray(values, np.float64) * 2.0**bits) / 2.0**bits).astype(np.float32)


def save_npz_compressed(path: str | Path, **arrays: np.ndarray) -> None:
    """A deflated npz (np.load reads it as any npz) written atomically, at NPZ_LEVEL."""
    with atomic.atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED, compresslevel=NPZ_LEVEL) as archive:
            for name, array in arrays.items():
                with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, np.asanyarray(array), allow_pickle=False)
