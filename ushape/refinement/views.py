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


# A mask with at least this fraction of its observed pixels foreground draws no outline: nothing to fit.
FULL_MASK = 0.995


def camera_problem(K: np.ndarray, world_to_cam: np.ndarray, image_hw: tuple[int, int] | None = None) -> str | None:
    """Why a camera cannot be used (None: it can): shapes, non-finite or singular values, a world_to_cam that is
    not a rigid motion, the object (the world origin, centre of the unit sphere) behind the camera, and, given
    the image's (H, W), a principal point outside it (K made for an image of another size)."""
    K, w2c = np.asarray(K, dtype=np.float64), np.asarray(world_to_cam, dtype=np.float64)
    if K.shape != (3, 3) or w2c.shape != (4, 4):
        return f"needs K [3, 3] and world_to_cam [4, 4], got {K.shape} and {w2c.shape}"
    for name, value in (("K", K), ("world_to_cam", w2c)):
        if not np.isfinite(value).all():
            return f"{name} holds NaN or inf values"
    if K[0, 0] <= 0 or K[1, 1] <= 0 or abs(np.linalg.det(K)) < 1e-9:
        return f"K is singular or has a focal length <= 0 (fx {K[0, 0]:.4g}, fy {K[1, 1]:.4g}): pass pixel intrinsics"
    rotation = w2c[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-3) or np.linalg.det(rotation) <= 0:
        return "world_to_cam's 3x3 block is not a rotation (a rigid world-to-camera motion is needed)"
    if w2c[2, 3] <= 0:
        return f"the object is behind the camera (the world origin's camera-frame z is {w2c[2, 3]:.3g}, must be > 0)"
    if image_hw is not None:
        (H, W), (cx, cy) = image_hw, (K[0, 2], K[1, 2])
        if not (0 <= cx <= W and 0 <= cy <= H):
            return (
                f"K's principal point ({cx:.1f}, {cy:.1f}) lies outside the {W}x{H} image: K was made for an image "
                "of another size"
            )
    return None


def check_view(view: ObservedView) -> None:
    """Raise a ValueError that says what to pass when a view's arrays do not fit together."""
    problem = camera_problem(view.K, view.world_to_cam)
    if problem is not None:
        raise ValueError(f"a view's camera: {problem}")
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


@dataclass(frozen=True)
class ScreenedView:
    """What the refinement takes of one view: the view (None: nothing), what it uses ("masks" or "masks+depth";
    None: nothing) and, where it uses less than asked, why (a named fallback)."""

    view: ObservedView | None
    used: str | None
    fallback: str | None = None

    def record(self) -> dict[str, str | None]:
        return {"used": self.used, "fallback": self.fallback}


def screen_view(view: ObservedView | None, use_depth: bool) -> ScreenedView:
    """The part of a view that carries information.

    No camera gives nothing. A whole image (no `observed` crop) whose mask is empty or all object gives
    nothing either: the object is in every input image, so its mask is wrong, and a mask with no outline
    would fit a blob. (A crop may rightly show only background or only object: it is kept.) Asked for
    depth, a view without finite depth returns gives its mask alone.
    """
    if view is None:
        return ScreenedView(None, None, "no camera")
    check_view(view)
    if view.observed is None:
        foreground = float((view.mask > 0.5).float().mean())
        if foreground == 0.0:
            return ScreenedView(None, None, "empty mask: the image shows no object")
        if foreground >= FULL_MASK:
            return ScreenedView(None, None, f"the mask is {100 * foreground:.1f} % object: it draws no outline")
    seen = view.seen().reshape(-1)
    if not use_depth:
        return ScreenedView(view, "masks")
    if view.depth is None:
        return ScreenedView(view, "masks", "no depth: masks only")
    depth = view.depth.reshape(-1)[seen]
    if not bool(torch.isfinite(depth).all()):
        return ScreenedView(replace(view, depth=None), "masks", "depth holds NaN or inf: masks only")
    if not bool((depth > 0).any()):
        return ScreenedView(replace(view, depth=None), "masks", "no depth return (all 0): masks only")
    return ScreenedView(view, "masks+depth")


def mask_box(view: ObservedView) -> tuple[float, float, float, float]:
    """(u0, v0, u1, v1) of the mask's observed foreground, pixel edges."""
    mask = (view.mask > 0.5) & view.seen()
    rows, cols = mask.any(1).nonzero().squeeze(1), mask.any(0).nonzero().squeeze(1)
    return float(cols.min()), float(rows.min()), float(cols.max() + 1), float(rows.max() + 1)
