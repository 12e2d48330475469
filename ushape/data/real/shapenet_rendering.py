"""ShapeNetRendering (3D-R2N2's renders of ShapeNetCore v1): images, metadata and cameras.

    <root>/<synset>/<model_id>/rendering/00.png .. 23.png          137x137 RGBA
    <root>/<synset>/<model_id>/rendering/rendering_metadata.txt   "az el inplane dist_ratio fov" per view

Cameras follow `ushape.data.cameras` (R2N2's Blender protocol). What is assumed about frames:
R2N2 rendered ShapeNetCore v1's OBJ after scaling it to a unit bounding-box diagonal about
its box centre. Centring and uniform scaling commute with our own normalisation, so the
box centre and diagonal of *our normalised mesh* (`r2n2_frame`) place the R2N2 cameras.
v1 and v2 do NOT share their axes: v2 turned every model 90 degrees about y (v1 faces +x,
v2 faces -z), so the cameras are built in the axes of the layout the mesh came from
(`frame="v1"` or `"v2"`); the box centre and diagonal are the same in both.
Object masks are the renders' alpha at >= 128 (`alpha_mask`): alpha > 0 would also count the
anti-aliased rim, about one pixel wider than the object all round, which costs thin chairs
~0.09 IoU. `render_agreement` (mask IoU between an R2N2 image and our render through its
camera; 0.996 mean, 0.991 worst view on the shared real chair) is recorded per shape so that
models whose v1 and v2 versions differ can be found and dropped; below AGREEMENT_WARNING a
warning names the model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from ushape.data.cameras import metadata_to_cameras, parse_metadata
from ushape.data.shape_artifacts import r2n2_frame

RENDERING_DIR = "rendering"
METADATA_FILE = "rendering_metadata.txt"
R2N2_IMAGE_SIZE = 137
ALPHA_THRESHOLD = 128  # of 255: the object's pixels, without the anti-aliased rim
AGREEMENT_WARNING = 0.9  # mean silhouette IoU under which a model's renders and mesh disagree
EXPECTED_LAYOUT = (
    "<root>/<synset>/<model_id>/rendering/{00..23}.png and rendering/rendering_metadata.txt "
    "(ShapeNetRendering.tgz from 3D-R2N2, unpacked)"
)


def rendering_dir(root: str | Path, synset: str, model_id: str) -> Path:
    return Path(root).expanduser() / synset / model_id / RENDERING_DIR


def check_root(root: str | Path, synset: str) -> Path:
    """The synset folder of a ShapeNetRendering root; a clear error when the layout does not match."""
    root = Path(root).expanduser()
    if not (root / synset).is_dir():
        raise FileNotFoundError(f"ShapeNetRendering root {root} has no folder {synset}. Expected {EXPECTED_LAYOUT}")
    return root / synset


def read_metadata(root: str | Path, synset: str, model_id: str) -> np.ndarray:
    """Metadata rows [V,5] (azimuth, elevation, in-plane, distance ratio, fov) of one model."""
    path = rendering_dir(root, synset, model_id) / METADATA_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing. Expected {EXPECTED_LAYOUT}")
    return parse_metadata(path.read_text())


def image_paths(root: str | Path, synset: str, model_id: str, n_views: int) -> list[Path]:
    """Paths of views 00..n_views-1; FileNotFoundError naming the first missing one."""
    folder = rendering_dir(root, synset, model_id)
    paths = [folder / f"{v:02d}.png" for v in range(n_views)]
    missing = [p for p in paths if not p.is_file()]
    if missing:
        raise FileNotFoundError(
            f"{len(missing)} of {n_views} renders missing, e.g. {missing[0]}. Expected {EXPECTED_LAYOUT}"
        )
    return paths


def load_rgba(path: str | Path, image_size: int) -> np.ndarray:
    """RGBA uint8 [S,S,4] of one render, resized (bilinear) when image_size is not R2N2's 137."""
    with Image.open(path) as image:
        image = image.convert("RGBA")
        if image.size != (image_size, image_size):
            image = image.resize((image_size, image_size), Image.BILINEAR)
        return np.asarray(image, dtype=np.uint8).copy()


def alpha_mask(rgba: np.ndarray) -> np.ndarray:
    """Object masks bool [..., H, W] of RGBA uint8 renders [..., H, W, 4]."""
    return rgba[..., 3] >= ALPHA_THRESHOLD


def model_cameras(
    rows: np.ndarray, mesh: trimesh.Trimesh, image_size: int, layout: str = "v1"
) -> tuple[np.ndarray, np.ndarray]:
    """(K [V,3,3], world_to_cam [V,4,4]) in the normalised mesh's frame from R2N2 rows [V,5].

    `layout` is the ShapeNetCore version ("v1" or "v2") whose axes the mesh is in.
    """
    centre, scale = r2n2_frame(mesh)
    return metadata_to_cameras(rows, image_size, r2n2_centre=centre, r2n2_scale=scale, frame=layout)


def render_agreement(r2n2_masks: np.ndarray, our_masks: np.ndarray) -> float:
    """Mean per-view IoU [] of R2N2 alpha masks [V,H,W] and our renders' masks [V,H,W]."""
    inter = np.logical_and(r2n2_masks, our_masks).sum(axis=(1, 2))
    union = np.logical_or(r2n2_masks, our_masks).sum(axis=(1, 2))
    return float(np.mean(np.where(union > 0, inter / np.maximum(union, 1), 1.0)))
