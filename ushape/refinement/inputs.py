"""The views reconstruct.py refines on, from its input images: each one's camera, mask and depth where known.

Cameras, in this order of precedence:
  - a camera file the user passes: an .npz laid out like the world's views.npz, one entry per input
    image in input order: K [V, 3, 3] (for each image's own pixel size), world_to_cam [V, 4, 4], and
    optionally masks [V, H, W] and depth [V, H, W] (camera-frame z, 0 = no return);
  - a render of our world (renders/<id>/NN.png with views.npz beside it): its own camera, mask and depth.
Masks, where the camera file has none: the mask files passed (one per image, white = object), else the
image's alpha. An image with no camera is returned as None: the refinement skips it, saying so.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from ushape.data.augment import read_image
from ushape.data.layout import VIEWS_FILE
from ushape.refinement.views import ObservedView, world_views

log = logging.getLogger(__name__)


def image_mask(path: str | Path, from_alpha: bool = True) -> torch.Tensor:
    """[H, W] float mask of an image: its alpha (from_alpha), else its grey level (a mask file), as 0 / 1."""
    rgba = read_image(path)
    level = rgba[..., 3] if from_alpha else rgba[..., :3].mean(-1)
    return torch.as_tensor(level > 0.5).float()


def camera_file_views(
    cameras: str | Path, images: Sequence[Path], masks: Sequence[Path] | None
) -> list[ObservedView | None]:
    """One ObservedView per image from a views.npz-like camera file (see the module docstring)."""
    with np.load(cameras) as data:
        if "K" not in data.files or "world_to_cam" not in data.files:
            raise ValueError(f"camera file {cameras} needs arrays K [V, 3, 3] and world_to_cam [V, 4, 4]")
        if len(data["K"]) != len(images):
            raise ValueError(f"camera file {cameras} has {len(data['K'])} cameras for {len(images)} input images")
        stored = {key: data[key] for key in ("masks", "depth") if key in data.files}
        Ks, w2cs = data["K"].astype(np.float64), data["world_to_cam"].astype(np.float64)
    views = []
    for i, image in enumerate(images):
        if "masks" in stored:
            mask = torch.as_tensor(stored["masks"][i]).float()
        elif masks is not None:
            mask = image_mask(masks[i], from_alpha=False)
        else:
            mask = image_mask(image)
        depth = torch.as_tensor(stored["depth"][i]).float() if "depth" in stored else None
        views.append(ObservedView(Ks[i], w2cs[i], mask, depth))
    return views


def render_view(views_npz: Path, index: int, image: Path, mask: Path | None) -> ObservedView:
    """A render's view from its views.npz; the mask file passed, else the stored mask, else the image's alpha."""
    with np.load(views_npz) as data:
        stored = "masks" in data.files
    if stored and mask is None:
        (view,) = world_views(views_npz, [index])
        return view
    with np.load(views_npz) as data:
        K, w2c = data["K"][index].astype(np.float64), data["world_to_cam"][index].astype(np.float64)
        depth = torch.as_tensor(data["depth"][index]).float() if "depth" in data.files else None
    found = image_mask(image) if mask is None else image_mask(mask, from_alpha=False)
    return ObservedView(K, w2c, found, depth)


def input_views(
    images: Sequence[Path], cameras: str | Path | None = None, masks: Sequence[Path] | None = None
) -> list[ObservedView | None]:
    """Per input image its ObservedView, or None where no camera is known (a photo without a camera file)."""
    if masks is not None and len(masks) != len(images):
        raise ValueError(f"{len(masks)} mask files for {len(images)} images: pass one mask per image, in order")
    if cameras is not None:
        return camera_file_views(cameras, images, masks)
    views = []
    for i, image in enumerate(images):
        render_views = Path(image).parent / VIEWS_FILE
        if render_views.is_file() and Path(image).stem.isdigit():
            views.append(render_view(render_views, int(Path(image).stem), image, None if masks is None else masks[i]))
        else:
            log.warning("%s has no camera (not a render of the world, no --cameras file): not refined", image)
            views.append(None)
    return views
