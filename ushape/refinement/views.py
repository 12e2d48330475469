"""What one calibrated view shows: its camera, its mask, its depth where it has one, and which pixels it saw.

A crop keeps the view's camera: cropping and resizing only change K. Pixels of a crop that fall
outside the original image are UNOBSERVED (`observed` False): they carry no likelihood, because a
photo cut off at the seat says nothing about the legs, and must not be read as background.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import Tensor


@dataclass(frozen=True)
class ObservedView:
    """One view: K [3, 3] for an image of mask's size, world_to_cam [4, 4], mask [H, W] in [0, 1],
    depth [H, W] (camera-frame z, 0 = no return) or None, observed [H, W] bool or None (all observed)."""

    K: np.ndarray
    world_to_cam: np.ndarray
    mask: Tensor
    depth: Tensor | None = None
    observed: Tensor | None = None

    @property
    def image_hw(self) -> tuple[int, int]:
        return int(self.mask.shape[0]), int(self.mask.shape[1])

    def seen(self) -> Tensor:  # [H, W] bool
        """The pixels that carry a likelihood."""
        return torch.ones(self.image_hw, dtype=torch.bool) if self.observed is None else self.observed


def check_view(view: ObservedView) -> None:
    """Raise a ValueError that says what to pass when a view's arrays do not fit together."""
    K, w2c = np.asarray(view.K), np.asarray(view.world_to_cam)
    if K.shape != (3, 3) or w2c.shape != (4, 4):
        raise ValueError(f"a view needs K [3, 3] and world_to_cam [4, 4], got {K.shape} and {w2c.shape}")
    if view.mask.ndim != 2:
        raise ValueError(f"a view's mask must be [H, W], got shape {tuple(view.mask.shape)}")
    for name in ("depth", "observed"):
        value = getattr(view, name)
        if value is not None and tuple(value.shape) != tuple(view.mask.shape):
            raise ValueError(
                f"a view's {name} must have the mask's shape {tuple(view.mask.shape)}, got {tuple(value.shape)}"
            )


def crop_camera(K: np.ndarray, box: tuple[int, int, int, int], out_hw: tuple[int, int]) -> np.ndarray:
    """K [3, 3] of the crop (top, left, h, w) of an image, resized to out_hw (pixel-centre convention)."""
    top, left, h, w = box
    shift = np.array([[1.0, 0.0, -left], [0.0, 1.0, -top], [0.0, 0.0, 1.0]])
    scale = np.diag([out_hw[1] / w, out_hw[0] / h, 1.0])
    return scale @ shift @ np.asarray(K, dtype=np.float64)


def crop_view(view: ObservedView, box: tuple[int, int, int, int], out_hw: tuple[int, int]) -> ObservedView:
    """The crop (top, left, h, w) of a view resized to out_hw by nearest pixel; outside the image: unobserved.

    The box may leave the image (a truncated photo): those pixels are marked unobserved, not background.
    """
    top, left, h, w = box
    H, W = view.image_hw
    rows = np.floor(top + (np.arange(out_hw[0]) + 0.5) * h / out_hw[0]).astype(int)
    cols = np.floor(left + (np.arange(out_hw[1]) + 0.5) * w / out_hw[1]).astype(int)
    inside = torch.as_tensor(((rows >= 0) & (rows < H))[:, None] & ((cols >= 0) & (cols < W))[None, :])
    r, c = torch.as_tensor(rows.clip(0, H - 1)), torch.as_tensor(cols.clip(0, W - 1))

    def take(image: Tensor | None) -> Tensor | None:
        return None if image is None else image[r][:, c]

    return replace(
        view,
        K=crop_camera(view.K, box, out_hw),
        mask=take(view.mask),
        depth=take(view.depth),
        observed=take(view.seen()) & inside,
    )


def world_views(views_npz: str | Path, indices: list[int] | None = None, with_depth: bool = True) -> list[ObservedView]:
    """The synthetic world's views of one shape (renders/<id>/views.npz: K, world_to_cam, masks, depth)."""
    with np.load(views_npz) as data:
        n = len(data["K"])
        chosen = list(range(n)) if indices is None else list(indices)
        bad = [i for i in chosen if not 0 <= i < n]
        if bad:
            raise ValueError(f"{views_npz} has views 0..{n - 1}; asked for {bad}")
        has_depth = with_depth and "depth" in data.files
        return [
            ObservedView(
                K=data["K"][i].astype(np.float64),
                world_to_cam=data["world_to_cam"][i].astype(np.float64),
                mask=torch.as_tensor(data["masks"][i]).float(),
                depth=torch.as_tensor(data["depth"][i]).float() if has_depth else None,
            )
            for i in chosen
        ]
