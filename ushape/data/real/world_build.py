"""What the real worlds (ShapeNet meshes, 3D-R2N2 voxels) build alike: their config and split files, the
models they skip and why, and each model's views (R2N2's images and cameras where given, else our renders of
R2N2's protocol) written as the world layout keeps them (`ushape.data.layout`).

Each world says where its models come from and how a model's surface and cameras are made; this module
writes what they have in common, so a third real source extends it rather than copying either.
"""

from __future__ import annotations

import hashlib
import io
import json
from pathlib import Path
from typing import Any, Callable

import numpy as np
from PIL import Image

from ushape import atomic
from ushape.data import integrity
from ushape.data.cameras import format_metadata, sample_r2n2_views
from ushape.data.layout import SPLITS, WorldIndex
from ushape.data.real import shapenet, shapenet_rendering
from ushape.errors import InputError
from ushape.workspace import SKIPPED_FILE

VIEWS_STREAM = 2  # the random stream of a model's own R2N2-protocol cameras (after its SDF samples' stream 1)


def view_source(
    renderings_root: str | None, synset: str, model_id: str, seed: int, n_views: int, size: int
) -> tuple[str, np.ndarray | None]:
    """(rendering_metadata.txt's text, R2N2's RGBA images [V, S, S, 4] or None): R2N2's own where
    renderings_root is given, else cameras drawn by R2N2's protocol (rendered by the caller)."""
    if renderings_root:
        rows = shapenet_rendering.read_metadata(renderings_root, synset, model_id)[:n_views]
        if len(rows) < n_views:
            raise FileNotFoundError(f"{model_id}: rendering metadata lists {len(rows)} views, need {n_views}")
        paths = shapenet_rendering.image_paths(renderings_root, synset, model_id, n_views)
        return format_metadata(rows), np.stack([shapenet_rendering.load_rgba(p, size) for p in paths])
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(VIEWS_STREAM,)))
    return format_metadata(sample_r2n2_views(n_views, rng)), None


def store_views(
    index: WorldIndex,
    model_id: str,
    text: str,
    rgba: np.ndarray | None,  # [V, S, S, 4] R2N2's images, or None: ours
    ours: dict,  # render_views' output through the cameras: rgba, mask, depth
    arrays: dict[str, np.ndarray],  # K, world_to_cam, depth, r2n2_centre, r2n2_scale as the world stores them
    save_npz: Callable[..., None] = atomic.save_npz,
    on_agreement: Callable[[float], None] | None = None,
) -> None:
    """The views' PNGs, rendering_metadata.txt and views.npz (the arrays, the masks: R2N2's alpha or ours, and
    with R2N2's images how far their masks agree with our renders, r2n2_mask_iou, also given to on_agreement)."""
    extra = {}
    if rgba is None:
        rgba, masks = ours["rgba"], ours["mask"]
    else:
        masks = shapenet_rendering.alpha_mask(rgba)
        iou = shapenet_rendering.render_agreement(masks, ours["mask"])
        if on_agreement is not None:
            on_agreement(iou)
        extra["r2n2_mask_iou"] = np.float32(iou)
    for view in range(len(rgba)):
        buffer = io.BytesIO()
        Image.fromarray(rgba[view], mode="RGBA").save(buffer, format="PNG")
        atomic.write_bytes(index.image_path(model_id, view), buffer.getvalue())
    atomic.write_text(index.metadata_path(model_id), text)
    arrays = dict(arrays)
    ordered = {"K": arrays.pop("K"), "world_to_cam": arrays.pop("world_to_cam"), "masks": masks}
    save_npz(index.views_path(model_id), **ordered, **arrays, **extra)


def split_fingerprint(source: shapenet.SplitSource) -> Any:
    """What identifies a split source in the config hash: paths and the SHA-256 of their contents."""
    if source is None:
        return None
    if isinstance(source, dict) or hasattr(source, "items"):
        return {k: split_fingerprint(v) for k, v in sorted(source.items())}
    path = Path(source).expanduser().resolve()
    files = sorted(path.glob("*.json")) if path.is_dir() else [path]
    digest = hashlib.sha256(b"".join(f.read_bytes() for f in files if f.is_file())).hexdigest()[:12]
    return {"path": str(path), "sha256": digest}


def checked_renderings_root(renderings_root: str | Path | None, synset: str, n_views: int) -> str | None:
    """The ShapeNetRendering root as an absolute path (None without one), checked to hold the synset and
    at least n_views renders per model (it has 24)."""
    if not renderings_root:
        return None
    root = str(Path(renderings_root).expanduser().resolve())
    shapenet_rendering.check_root(root, synset)
    if int(n_views) > 24:
        raise InputError(f"ShapeNetRendering has 24 views per model; n_views={n_views} is too many")
    return root


def write_splits(
    index: WorldIndex, planned: dict[str, list[str]], skipped: dict[str, str], source: str, layout: str
) -> None:
    """skipped.json, and each split's file as planned less the skipped models (rewritten only when it changed);
    an InputError naming `source` when no training shape is left."""
    atomic.write_json(index.root / SKIPPED_FILE, skipped)
    splits = {s: [m for m in planned[s] if m not in skipped] for s in SPLITS}
    if not splits["train"]:
        raise InputError(
            f"no usable training shape in {source}: {len(skipped)} skipped "
            f"(see {index.root / SKIPPED_FILE}); check the split file and {layout}"
        )
    for split in SPLITS:
        if json_differs(index.split_path(split), splits[split]):
            atomic.write_json(index.split_path(split), splits[split])


def json_differs(path: Path, value: Any) -> bool:
    """Whether the JSON file at path is missing, damaged or holds something other than value."""
    if integrity.check_json(path) is not None:
        return True
    return json.loads(path.read_text()) != value


def read_skipped(path: Path) -> dict[str, str]:
    """model id -> why it was skipped, from skipped.json ({} where there is none or it is damaged)."""
    if integrity.check_json(path) is not None:
        return {}
    data = json.loads(path.read_text())
    return {str(k): str(v) for k, v in data.items()} if isinstance(data, dict) else {}
