"""ShapeNetCore preprocessed into the world layout that training reads (`ushape.data.layout`).

    <cache_root>/shapenet/<synset>-<hash12>/   config.json, splits/, meshes/, sdf/, renders/,
                                                shapes/, skipped.json

Per model: the OBJ is loaded with its material/texture colours, normalised to DeepSDF's unit
sphere, sampled for SDF with `ushape.data.real.mesh_sdf` (robust sign for real meshes; shapes/<id>.json
keeps the sign report as `sdf_signs`, see the README's real-data section), and given
views: ShapeNetRendering's images and cameras when `renderings_root` is set, otherwise our own
R2N2-protocol renders. A model that cannot be processed is logged, listed in skipped.json with
its reason and left out of the splits; it is not retried while the config (hence the folder)
is unchanged. Every file is written atomically and existing valid files are kept, so an
interrupted build resumes where it stopped.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Optional, Sequence

import numpy as np
import trimesh

from ushape import atomic
from ushape.data.cameras import parse_metadata
from ushape.data.jobs import run_jobs
from ushape.data.layout import SPLITS, WorldIndex
from ushape.data.real import shapenet, shapenet_rendering
from ushape.data.real.mesh_sdf import MeshProcessingError, load_mesh, normalise_mesh, previous_signs, sample_mesh_sdf
from ushape.data.real.world_build import (
    checked_renderings_root,
    json_differs,
    read_skipped,
    split_fingerprint,
    store_views,
    view_source,
    write_splits,
)
from ushape.data.rendering import render_views
from ushape.data.shape_artifacts import artifact_problems, r2n2_frame
from ushape.errors import InputError
from ushape.workspace import CONFIG_FILE, SKIPPED_FILE

log = logging.getLogger(__name__)

# 2: R2N2 cameras in the layout's axes (v1 or v2), azimuth as R2N2's; alpha >= 128 masks
# 3: SDF signs by winding number; shapes/<id>.json records how sure they are (sdf_signs)
# 4: SDF signs by reachability from outside (the official voxels' convention); sdf_signs reports method dependence
PREPROCESS_VERSION = 4

SDF_STREAM = 1  # a model's SDF samples' random stream (its views': world_build.VIEWS_STREAM)


@dataclass(frozen=True)
class ModelJob:
    index: WorldIndex
    model_id: str
    split: str
    source: str  # the model's OBJ path
    layout: str
    synset: str
    renderings_root: Optional[str]
    seed: int


class ShapeNetWorld:
    """Builds (once) and caches one ShapeNet category as a world; `build()` returns its WorldIndex."""

    # Config keys naming folders it reads: checked to exist before a run starts (training.validation).
    INPUT_FOLDERS = ("root", "renderings_root")

    def __init__(
        self,
        category: str,
        root: str,
        cache_root: str,
        split_file: shapenet.SplitSource = None,
        renderings_root: Optional[str] = None,
        samples_per_shape: int = 250_000,
        n_views: int = 24,
        image_size: int = 137,
        seed: int = 0,
        max_shapes: Optional[int] = None,
        num_workers: int = 0,
        split_fractions: Sequence[float] = shapenet.DEFAULT_FRACTIONS,
    ) -> None:
        for name, value in (("samples_per_shape", samples_per_shape), ("n_views", n_views), ("image_size", image_size)):
            if int(value) < 1:
                raise InputError(f"{name} must be positive, got {value}")
        if max_shapes is not None and int(max_shapes) < 1:
            raise InputError(f"max_shapes must be positive or None, got {max_shapes}")
        self.synset = shapenet.synset_id(category)
        self.root = Path(root).expanduser().resolve()
        self.layout, self.available = shapenet.list_models(self.root, self.synset)
        self.renderings_root = checked_renderings_root(renderings_root, self.synset, n_views)
        self.cache_root = Path(cache_root).expanduser()
        self.split_file = split_file
        self.num_workers = int(num_workers)
        self.config: dict[str, Any] = {
            "dataset": "shapenet",
            "category": str(category),
            "synset": self.synset,
            "root": str(self.root),
            "layout": self.layout,
            "renderings_root": self.renderings_root,
            "split": split_fingerprint(split_file),
            "split_fractions": [float(f) for f in split_fractions],
            "samples_per_shape": int(samples_per_shape),
            "n_views": int(n_views),
            "image_size": int(image_size),
            "seed": int(seed),
            "max_shapes": None if max_shapes is None else int(max_shapes),
            "preprocess_version": PREPROCESS_VERSION,
        }

    @property
    def directory(self) -> Path:
        digest = hashlib.sha256(json.dumps(self.config, sort_keys=True).encode()).hexdigest()[:12]
        return self.cache_root / "shapenet" / f"{self.synset}-{digest}"

    def planned_splits(self) -> dict[str, list[str]]:
        """Model ids per split before any skipping (split file or hash split, capped by max_shapes)."""
        if self.split_file is None:
            splits = shapenet.hash_split(self.available, self.config["split_fractions"])
        else:
            splits = shapenet.read_split_source(self.split_file, self.synset)
        cap = self.config["max_shapes"]
        if cap is not None:
            splits = {s: sorted(ids, key=lambda i: (shapenet.id_hash(i), i))[:cap] for s, ids in splits.items()}
        return splits

    def build(self) -> WorldIndex:
        """Preprocess whatever is missing (idempotent) and return the world's index."""
        start = time.perf_counter()
        root = self.directory
        if json_differs(root / CONFIG_FILE, self.config):
            atomic.write_json(root / CONFIG_FILE, self.config)
        planned = self.planned_splits()
        skipped = read_skipped(root / SKIPPED_FILE)
        available = set(self.available)
        for ids in planned.values():
            for mid in ids:
                if mid not in available and mid not in skipped:
                    skipped[mid] = (
                        f"listed in the split but "
                        f"{shapenet.model_path(self.root, self.synset, mid, self.layout)} is missing"
                    )
        index = WorldIndex(root=root, category=self.config["category"], splits=planned, config=self.config)
        jobs = [
            self._job(index, split, mid)
            for split in SPLITS
            for mid in dict.fromkeys(planned[split])
            if mid not in skipped
        ]
        jobs = list({j.model_id: j for j in jobs}.values())  # val/test may share a model
        for model_id, reason in self._run(jobs):
            if reason is not None:
                log.warning("skipping ShapeNet model %s: %s", model_id, reason)
                skipped[model_id] = reason
        write_splits(index, planned, skipped, f"{self.synset} under {self.root}", "the dataset layout")
        log.info(
            "ShapeNet %s world %s ready in %.1fs (%d skipped)",
            self.synset,
            root,
            time.perf_counter() - start,
            len(skipped),
        )
        return WorldIndex.load(root)

    def _job(self, index: WorldIndex, split: str, model_id: str) -> ModelJob:
        source = shapenet.model_path(self.root, self.synset, model_id, self.layout)
        seed = int(np.random.SeedSequence([self.config["seed"], shapenet.id_hash(model_id)]).generate_state(1)[0])
        return ModelJob(index, model_id, split, str(source), self.layout, self.synset, self.renderings_root, seed)

    def _run(self, jobs: list[ModelJob]) -> Iterable[tuple[str, Optional[str]]]:
        return run_jobs(process_model, jobs, self.num_workers, desc=f"ShapeNet {self.synset}", unit="model")


def process_model(job: ModelJob) -> tuple[str, Optional[str]]:
    """Make one model's missing artifacts; (model id, None) or (model id, reason it was skipped)."""
    problems = artifact_problems(job.index, job.model_id)
    if not problems:
        return job.model_id, None
    try:
        mesh, centre, scale = normalise_mesh(load_mesh(job.source))
        if "mesh" in problems:
            atomic.write_bytes(
                job.index.mesh_path(job.model_id), trimesh.exchange.ply.export_ply(mesh, encoding="binary")
            )
        signs = None if "sdf" in problems else previous_signs(job.index.shape_path(job.model_id))
        if "sdf" in problems:
            rng = np.random.default_rng(np.random.SeedSequence(job.seed, spawn_key=(SDF_STREAM,)))
            samples, report = sample_mesh_sdf(mesh, int(job.index.config["samples_per_shape"]), rng)
            atomic.save_npz(job.index.sdf_path(job.model_id), **samples)
            signs = report.as_dict()
        if "renders" in problems:
            write_model_views(job, mesh)
    except (MeshProcessingError, FileNotFoundError) as err:
        return job.model_id, f"{type(err).__name__}: {err}"
    atomic.write_json(
        job.index.shape_path(job.model_id),
        {
            "shape_id": job.model_id,
            "category": job.index.category,
            "synset": job.synset,
            "split": job.split,
            "source": job.source,
            "layout": job.layout,
            "centre": centre.tolist(),
            "scale": float(scale),
            "views": "shapenet_rendering" if job.renderings_root else "ushape",
            "sdf_signs": signs,
        },
    )
    return job.model_id, None


def write_model_views(job: ModelJob, mesh: trimesh.Trimesh) -> None:
    """PNGs, rendering_metadata.txt and views.npz of one model: R2N2's images if given, else ours."""
    index, n_views, size = job.index, int(job.index.config["n_views"]), int(job.index.config["image_size"])
    text, rgba = view_source(job.renderings_root, job.synset, job.model_id, job.seed, n_views, size)
    centre, scale = r2n2_frame(mesh)
    # R2N2's files store 25 in the fov column, which is not the lens it rendered with; ours store
    # the true one. Either way the protocol's lens is right (see ushape.data.cameras).
    Ks, world_to_cams = shapenet_rendering.model_cameras(parse_metadata(text), mesh, size, job.layout)
    ours = render_views(mesh, Ks, world_to_cams, size)

    def agreement(iou: float) -> None:
        if iou < shapenet_rendering.AGREEMENT_WARNING:
            log.warning(
                "%s: R2N2 images overlap our renders through their cameras by IoU %.2f only (real "
                "ShapeNet chairs: > 0.99); this %s model's frame may differ from the one R2N2 rendered "
                "(see ushape.data.real.shapenet_rendering)",
                job.model_id,
                iou,
                job.layout,
            )

    arrays = {
        "K": Ks.astype(np.float32),
        "world_to_cam": world_to_cams.astype(np.float32),
        "depth": ours["depth"].astype(np.float32),
        "r2n2_centre": centre.astype(np.float32),
        "r2n2_scale": np.float32(scale),
    }
    store_views(index, job.model_id, text, rgba, ours, arrays, on_agreement=agreement)
