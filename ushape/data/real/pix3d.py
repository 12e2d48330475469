"""Pix3D: real photos aligned with IKEA models, for evaluation (single view and Pix3D-MV).

    <root>/pix3d.json                     one entry per image (img, mask, model, category, bbox, ...)
    <root>/img/<category>/<name>.<ext>    photos;  <root>/mask/<category>/<name>.png  object masks
    <root>/model/<category>/<NAME>/model.obj, voxel.mat (128^3 occupancy), 3d_keypoints.txt

Images are cropped to a square around their annotated bbox (plus a margin) and returned as
premultiplied RGBA, alpha = the ground-truth mask (`mask_mode="gt_mask"`, background removed)
or 1 (`"none"`, the photo as is); the augment module's transforms composite them like renders.
Pix3D-MV (the paper's multi-view set: 149 chair instances, 1490 images) groups the images of
each model, sorted by file name, into chunks of `group_size` and drops the remainder. It takes
the images of Pix3D's official evaluation list, i.e. those neither truncated, occluded nor
slightly occluded (the filters `Pix3DWorld` and conf/data/pix3d.yaml apply by default); a model
is the json's `model` file, so each per-image variant of a swivel chair is a model of its own.

As an evaluation world, see `ushape.data.real.pix3d_world` (what `eval.py data=pix3d` reads).

voxel.mat frame, found by matching occupied voxels to the model's surface on the sample
models (and checked in tests): the grid spans the model's longest bounding-box side about the
box centre, and voxel axes (i, j, k) run along the model's (x, -z, y). `voxel_to_model`
gives that map; the voxels hold filled solids, so they also check our SDF signs.
"""

from __future__ import annotations

import json
import logging
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import numpy as np
import scipy.io
import torch
import trimesh
from PIL import Image
from torch import Tensor
from torch.utils.data import Dataset

from ushape.data.augment import MASK_MODES, build_transform
from ushape.errors import InputError, MissingInputError

log = logging.getLogger(__name__)

ANNOTATIONS_FILE = "pix3d.json"
CATEGORY_NAMES = {"chairs": "chair", "tables": "table"}
VOXEL_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # rows: model axis of voxel i, j, k
EXPECTED_LAYOUT = __doc__.split("\n\n")[1]


@dataclass(frozen=True)
class Pix3DEntry:
    """One annotated photo; paths are relative to the Pix3D root, bbox is (x0, y0, x1, y1) pixels."""

    img: str
    mask: str
    model: str
    category: str
    bbox: tuple[float, float, float, float]
    img_size: tuple[int, int]  # (width, height)
    truncated: bool = False
    occluded: bool = False
    slightly_occluded: bool = False
    rot_mat: Optional[tuple] = None
    trans_mat: Optional[tuple] = None
    focal_length: Optional[float] = None

    @property
    def model_id(self) -> str:
        """File-safe model id, e.g. "chair__IKEA_IVAR" for model/chair/IKEA_IVAR/model.obj."""
        parts = Path(self.model).with_suffix("").parts
        parts = parts[1:] if parts and parts[0] == "model" else parts
        parts = parts[:-1] if len(parts) > 1 and parts[-1] == "model" else parts
        return "__".join(parts)


def pix3d_category(category: str) -> str:
    """Pix3D's category name ("chair") from ours ("chairs") or itself."""
    return CATEGORY_NAMES.get(category, category)


def parse_entry(raw: dict[str, Any]) -> Pix3DEntry:
    """A Pix3DEntry from one pix3d.json record; ValueError naming the missing keys."""
    missing = [k for k in ("img", "mask", "model", "category", "bbox", "img_size") if k not in raw]
    if missing:
        raise InputError(f"pix3d.json entry {raw.get('img', '?')} lacks {missing}")
    as_tuple = lambda v: None if v is None else tuple(tuple(r) if isinstance(r, list) else r for r in v)  # noqa: E731
    return Pix3DEntry(
        img=raw["img"],
        mask=raw["mask"],
        model=raw["model"],
        category=raw["category"],
        bbox=tuple(float(b) for b in raw["bbox"]),
        img_size=tuple(int(s) for s in raw["img_size"]),
        truncated=bool(raw.get("truncated", False)),
        occluded=bool(raw.get("occluded", False)),
        slightly_occluded=bool(raw.get("slightly_occluded", False)),
        rot_mat=as_tuple(raw.get("rot_mat")),
        trans_mat=as_tuple(raw.get("trans_mat")),
        focal_length=raw.get("focal_length"),
    )


def load_annotations(
    root: str | Path,
    category: Optional[str] = None,
    drop_truncated: bool = False,
    drop_occluded: bool = False,
    drop_slightly_occluded: bool = False,
) -> list[Pix3DEntry]:
    """Entries of pix3d.json, filtered by category and occlusion flags, in file order."""
    path = Path(root).expanduser() / ANNOTATIONS_FILE
    if not path.is_file():
        raise MissingInputError(f"{path} does not exist. Expected Pix3D's layout:\n{EXPECTED_LAYOUT}")
    try:
        records = json.loads(path.read_text())
    except ValueError as err:
        raise InputError(f"{path} is not valid JSON ({err}); re-download pix3d.json") from err
    if not isinstance(records, list):
        raise InputError(f"{path} must hold a JSON list of image entries")
    entries = [parse_entry(r) for r in records]
    if category is not None:
        wanted = pix3d_category(category)
        entries = [e for e in entries if e.category == wanted]
    return [
        e
        for e in entries
        if not (drop_truncated and e.truncated)
        and not (drop_occluded and e.occluded)
        and not (drop_slightly_occluded and e.slightly_occluded)
    ]


def multiview_groups(entries: Sequence[Pix3DEntry], group_size: int = 10) -> list[list[int]]:
    """Pix3D-MV: entry indices per instance, `group_size` images of one model each, remainders dropped."""
    if group_size < 1:
        raise InputError(f"group_size must be positive, got {group_size}")
    by_model: dict[str, list[int]] = defaultdict(list)
    for i, entry in enumerate(entries):
        by_model[entry.model_id].append(i)
    groups = []
    for model_id in sorted(by_model):
        ordered = sorted(by_model[model_id], key=lambda i: entries[i].img)
        groups += [ordered[s : s + group_size] for s in range(0, len(ordered) - group_size + 1, group_size)]
    return groups


def square_box(bbox: Sequence[float], margin: float = 0.1) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1) of a square centred on bbox, side = longer bbox side * (1 + 2 * margin)."""
    x0, y0, x1, y1 = (float(b) for b in bbox)
    if x1 <= x0 or y1 <= y0:
        raise ValueError(f"bbox must be (x0, y0, x1, y1) with x1 > x0 and y1 > y0, got {tuple(bbox)}")
    if margin < 0:
        raise InputError(f"margin must be non-negative, got {margin}")
    half = max(x1 - x0, y1 - y0) * (1.0 + 2.0 * margin) / 2.0
    cx, cy = (x0 + x1) / 2.0, (y0 + y1) / 2.0
    return cx - half, cy - half, cx + half, cy + half


def crop_resize(image: Image.Image, box: Sequence[float], size: int, fill: Any = None) -> Image.Image:
    """Crop `box` (may leave the image: the outside is `fill`, default transparent/zero) and resize to size x size.

    The crop is cut at about the photo's own resolution and then resized, which filters over every
    source pixel: a Pix3D photo is often 1000+ px across, and sampling it straight down to 224 px
    (a transform's bilinear taps) would alias.
    """
    side = max(size, round(max(box[2] - box[0], box[3] - box[1])))
    crop = image.transform((side, side), Image.EXTENT, tuple(box), resample=Image.BILINEAR, fillcolor=fill)
    return crop if side == size else crop.resize((size, size), Image.BILINEAR)


def open_photo(root: Path, entry: Pix3DEntry) -> tuple[Image.Image, Image.Image]:
    """(RGB photo, L ground-truth mask) of one entry, both checked to exist and to share a size."""
    img_path, mask_path = root / entry.img, root / entry.mask
    for path in (img_path, mask_path):
        if not path.is_file():
            raise FileNotFoundError(f"{path} is missing. Expected Pix3D's layout:\n{EXPECTED_LAYOUT}")
    with Image.open(img_path) as img, Image.open(mask_path) as msk:
        rgb, mask = img.convert("RGB"), msk.convert("L")
    if mask.size != rgb.size:
        raise ValueError(f"{mask_path} is {mask.size}, but its image {img_path} is {rgb.size}")
    return rgb, mask


def view_rgba(root: Path, entry: Pix3DEntry, size: int, margin: float) -> np.ndarray:
    """RGBA uint8 [S,S,4] of one photo as a world view: its bbox crop, white outside the photo, alpha = GT mask."""
    rgb, mask = open_photo(root, entry)
    box = square_box(entry.bbox, margin)
    crop = crop_resize(rgb, box, size, fill=(255, 255, 255))
    crop.putalpha(crop_resize(mask, box, size, fill=0))
    return np.asarray(crop, dtype=np.uint8)


def load_crop(root: Path, entry: Pix3DEntry, size: int, margin: float, mask_mode: str) -> tuple[Tensor, Tensor]:
    """(premultiplied RGBA [4,S,S] in [0,1], ground-truth mask [1,S,S] in [0,1]) of one entry."""
    if mask_mode not in MASK_MODES:
        raise InputError(f"mask_mode must be one of {MASK_MODES}, got {mask_mode!r}")
    rgb, mask = open_photo(root, entry)
    alpha = mask if mask_mode == "gt_mask" else Image.new("L", rgb.size, 255)
    rgba = rgb.copy()
    rgba.putalpha(alpha)
    box = square_box(entry.bbox, margin)
    crop = np.asarray(crop_resize(rgba, box, size), np.float32) / 255.0
    mask_crop = np.asarray(crop_resize(mask, box, size), np.float32) / 255.0
    image = torch.from_numpy(crop).permute(2, 0, 1).contiguous()
    image[:3] *= image[3:]
    return image, torch.from_numpy(mask_crop)[None]


class Pix3DImages(Dataset):
    """Cropped Pix3D photos -> dict(image, mask [1,image_size,image_size], model_id, group, view, img).

    `transform(rgba, generator)` maps the premultiplied RGBA crop to the encoder's input (default:
    resize to `image_size` and composite on white, which also fills crop areas outside the photo). With
    `multiview`, items are only the images of Pix3D-MV groups, `group` is the instance index and `view`
    the position in it; otherwise every filtered image is an item and `group`/`view` are -1.
    """

    def __init__(
        self,
        root: str | Path,
        category: str = "chair",
        image_size: int = 137,
        crop_size: int = 224,
        margin: float = 0.1,
        mask_mode: str = "gt_mask",
        drop_truncated: bool = False,
        drop_occluded: bool = False,
        drop_slightly_occluded: bool = False,
        multiview: bool = False,
        group_size: int = 10,
        transform: Optional[Callable[..., Tensor]] = None,
    ) -> None:
        if mask_mode not in MASK_MODES:
            raise InputError(f"mask_mode must be one of {MASK_MODES}, got {mask_mode!r}")
        self.root = Path(root).expanduser()
        self.entries = load_annotations(self.root, category, drop_truncated, drop_occluded, drop_slightly_occluded)
        if multiview:
            self.groups = multiview_groups(self.entries, group_size)
            self.items = [(i, g, v) for g, members in enumerate(self.groups) for v, i in enumerate(members)]
        else:
            self.groups = []
            self.items = [(i, -1, -1) for i in range(len(self.entries))]
        if not self.items:
            raise InputError(f"no Pix3D images of category {category!r} left after filtering under {self.root}")
        self.crop_size, self.margin, self.mask_mode = int(crop_size), float(margin), mask_mode
        self.image_size = int(image_size)
        # The crop's alpha already encodes mask_mode; compositing on plain white only fills what
        # lies outside the photo (or outside the mask in gt_mask mode).
        self.transform = transform or build_transform(image_size, train=False, mask_mode="gt_mask")

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, index: int) -> dict:
        entry_index, group, view = self.items[index]
        entry = self.entries[entry_index]
        rgba, mask = load_crop(self.root, entry, self.crop_size, self.margin, self.mask_mode)
        if mask.shape[-1] != self.image_size:
            mask = torch.nn.functional.interpolate(mask[None], size=(self.image_size,) * 2, mode="bilinear")[0]
        return {
            "image": self.transform(rgba, None),
            "mask": mask,
            "model_id": entry.model_id,
            "group": group,
            "view": view,
            "img": entry.img,
        }


def load_voxels(path: str | Path) -> np.ndarray:
    """Occupancy bool [128,128,128] from a Pix3D voxel.mat, indexed (i, j, k) as in the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing. Expected Pix3D's layout:\n{EXPECTED_LAYOUT}")
    data = scipy.io.loadmat(path)
    if "voxel" not in data or data["voxel"].ndim != 3:
        raise ValueError(f"{path} has no 3-D 'voxel' array (keys: {sorted(k for k in data if not k.startswith('__'))})")
    return data["voxel"] > 0


def voxel_to_model(mesh: trimesh.Trimesh, resolution: int = 128) -> np.ndarray:
    """[4,4] map from homogeneous voxel indices (i, j, k, 1) of voxel centres to model coordinates."""
    lo, hi = mesh.bounds
    side = float((hi - lo).max())
    step = side / resolution
    transform = np.eye(4)
    transform[:3, :3] = VOXEL_AXES.T * step
    transform[:3, 3] = (lo + hi) / 2.0 + VOXEL_AXES.T @ np.full(3, (0.5 - resolution / 2.0) * step)
    return transform
