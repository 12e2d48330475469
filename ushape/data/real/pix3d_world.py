"""Pix3D as an evaluation world: its models of one category normalised and sampled, its photos as the views.

As an evaluation world (`Pix3DWorld.build()`, what `eval.py data=pix3d` reads), every model of
the test split has one view per filtered photo, in file-name order: renders/<model>/NN.png is
the photo's square crop, RGB outside the photo white, alpha = the ground-truth mask. Evaluation
reads it with the mask (Table 1's "w/ GT Mask" rows, and Pix3D-MV) and without ("w/o Mask": the
RGB as is, background included); config.json lists the views per model.

Every model is a test shape (train.py refuses the world); a model whose mesh or photos cannot be read is
skipped and listed in skipped.json.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
from collections import defaultdict
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np
import trimesh
from PIL import Image
from torch import Tensor

from ushape import atomic
from ushape.data import integrity
from ushape.data.layout import WorldIndex
from ushape.data.real.mesh_sdf import MeshProcessingError, load_mesh, normalise_mesh, previous_signs, sample_mesh_sdf
from ushape.data.real.pix3d import Pix3DEntry, Pix3DImages, load_annotations, pix3d_category, view_rgba
from ushape.errors import InputError
from ushape.workspace import CONFIG_FILE, SKIPPED_FILE

log = logging.getLogger(__name__)

# 2: renders/ holds the filtered photos' crops (one view per photo)
# 3: SDF signs by winding number; shapes/<id>.json records how sure they are (sdf_signs)
# 4: SDF signs by reachability from outside (the official voxels' convention); sdf_signs reports method dependence
PREPROCESS_VERSION = 4
MASK_INPUTS = ("gt_mask", "none")  # how evaluation may read the views: with the GT mask, or the photo as is


class Pix3DWorld:
    """Pix3D's models of one category preprocessed into the world layout (all in the test split).

    meshes/ and sdf/ as for ShapeNet, shapes/<id>.json with the normalisation (centre, scale)
    that maps Pix3D's model frame (where rot_mat/trans_mat and voxel.mat live) to ours and the
    photos behind its views, renders/<id>/NN.png one cropped photo per view (see the module doc).
    Pix3D's models share ShapeNetCore.v2's axes (y up, backs towards +z), so encoders trained on
    ShapeNet v2 meshes are scored in their own frame. `images(...)` gives the same photos as a
    Dataset with on-the-fly crops.
    """

    # Config keys naming folders it reads: checked to exist before a run starts (training.validation).
    INPUT_FOLDERS = ("root",)

    EVALUATION_ONLY = True  # every model is a test shape: train.py refuses it (training.validation)

    def __init__(
        self,
        category: str,
        root: str,
        cache_root: str,
        samples_per_shape: int = 250_000,
        seed: int = 0,
        image_size: int = 224,
        margin: float = 0.1,
        mask_mode: str = "gt_mask",
        group_size: int = 10,
        drop_truncated: bool = True,
        drop_occluded: bool = True,
        drop_slightly_occluded: bool = True,
    ) -> None:
        self.root = Path(root).expanduser().resolve()
        self.category = pix3d_category(category)
        self.filters = dict(
            drop_truncated=bool(drop_truncated),
            drop_occluded=bool(drop_occluded),
            drop_slightly_occluded=bool(drop_slightly_occluded),
        )
        self.image_options = dict(image_size=image_size, margin=margin, mask_mode=mask_mode, group_size=group_size)
        self.config = {
            "dataset": "pix3d",
            "category": self.category,
            "root": str(self.root),
            "samples_per_shape": int(samples_per_shape),
            "seed": int(seed),
            "image_size": int(image_size),
            "margin": float(margin),
            **self.filters,
            "preprocess_version": PREPROCESS_VERSION,
            # Read by the evaluation: Pix3D-MV drops a model's last images short of a group, and
            # Table 1 has rows with and without the ground-truth mask.
            "drop_short_instances": True,
            "mask_inputs": list(MASK_INPUTS),
        }
        self.cache_root = Path(cache_root).expanduser()

    @property
    def directory(self) -> Path:
        digest = hashlib.sha256(json.dumps(self.config, sort_keys=True).encode()).hexdigest()[:12]
        return self.cache_root / "pix3d" / f"{self.category}-{digest}"

    def model_files(self) -> dict[str, Path]:
        """model id -> OBJ path of every model the category's photos refer to."""
        entries = load_annotations(self.root, self.category, **self.filters)
        return {e.model_id: self.root / e.model for e in sorted(entries, key=lambda e: e.model_id)}

    def model_photos(self) -> dict[str, list[Pix3DEntry]]:
        """model id -> its filtered photos in file-name order (the model's views, as Pix3D-MV orders them)."""
        by_model: dict[str, list[Pix3DEntry]] = defaultdict(list)
        for entry in load_annotations(self.root, self.category, **self.filters):
            by_model[entry.model_id].append(entry)
        return {m: sorted(entries, key=lambda e: e.img) for m, entries in sorted(by_model.items())}

    def build(self) -> WorldIndex:
        """Normalise, sample and crop the views of every model of the category that is missing (idempotent);
        skip models whose mesh or photos cannot be read."""
        root = self.directory
        photos = self.model_photos()
        index = WorldIndex(root=root, category=self.category, splits={}, config=self.config)
        skipped: dict[str, str] = {}
        for model_id, entries in photos.items():
            try:
                process_pix3d_model(index, model_id, self.root / entries[0].model)
                write_pix3d_views(index, model_id, self.root, entries, float(self.config["margin"]))
            except (MeshProcessingError, FileNotFoundError, ValueError) as err:
                log.warning("skipping Pix3D model %s: %s", model_id, err)
                skipped[model_id] = f"{type(err).__name__}: {err}"
        ids = sorted(set(photos) - set(skipped))
        if not ids:
            raise InputError(f"no usable Pix3D {self.category} model under {self.root} ({len(skipped)} skipped)")
        views = {m: len(photos[m]) for m in ids}
        atomic.write_json(root / CONFIG_FILE, {**self.config, "n_views": max(views.values()), "views_per_shape": views})
        atomic.write_json(root / SKIPPED_FILE, skipped)
        for split, split_ids in (("train", []), ("val", []), ("test", ids)):
            atomic.write_json(index.split_path(split), split_ids)
        return WorldIndex.load(root)

    def images(self, multiview: bool = False, transform: Optional[Callable[..., Tensor]] = None) -> Pix3DImages:
        """The category's cropped photos (Pix3D-MV groups with multiview=True)."""
        return Pix3DImages(
            self.root, self.category, multiview=multiview, transform=transform, **self.image_options, **self.filters
        )


def write_pix3d_views(
    index: WorldIndex, model_id: str, root: Path, entries: Sequence[Pix3DEntry], margin: float
) -> None:
    """renders/<model>/NN.png, one cropped photo per entry, unless already there; the photos go into the record."""
    size = int(index.config["image_size"])
    for view, entry in enumerate(entries):
        path = index.image_path(model_id, view)
        if integrity.check_png(path, (size, size)) is not None:
            buffer = io.BytesIO()
            Image.fromarray(view_rgba(root, entry, size, margin), mode="RGBA").save(buffer, format="PNG")
            atomic.write_bytes(path, buffer.getvalue())
    record = json.loads(index.shape_path(model_id).read_text())
    images = [e.img for e in entries]
    if record.get("images") != images:
        atomic.write_json(index.shape_path(model_id), {**record, "images": images})


def process_pix3d_model(index: WorldIndex, model_id: str, source: Path) -> None:
    """Write one model's normalised mesh, SDF samples and record unless they are already valid."""
    mesh_ok = integrity.check_ply(index.mesh_path(model_id)) is None
    sdf_ok = integrity.check_npz(index.sdf_path(model_id), {"pos": (None, 4), "neg": (None, 4)}) is None
    if mesh_ok and sdf_ok and integrity.check_json(index.shape_path(model_id)) is None:
        return
    mesh, centre, scale = normalise_mesh(load_mesh(source))
    if not mesh_ok:
        atomic.write_bytes(index.mesh_path(model_id), trimesh.exchange.ply.export_ply(mesh, encoding="binary"))
    signs = previous_signs(index.shape_path(model_id)) if sdf_ok else None
    if not sdf_ok:
        seed = np.random.SeedSequence([int(index.config["seed"]), *model_id.encode()])
        samples, report = sample_mesh_sdf(mesh, int(index.config["samples_per_shape"]), np.random.default_rng(seed))
        atomic.save_npz(index.sdf_path(model_id), **samples)
        signs = report.as_dict()
    atomic.write_json(
        index.shape_path(model_id),
        {
            "shape_id": model_id,
            "category": index.category,
            "source": str(source),
            "centre": centre.tolist(),
            "scale": float(scale),
            "sdf_signs": signs,
        },
    )
