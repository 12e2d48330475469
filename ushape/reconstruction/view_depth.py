"""Depth maps of the reconstruction along each input view's camera: its mean depth and depth std.

Cameras: an input that is a render of our world (`renders/<id>/NN.png` with `views.npz` beside it) is
traced from its own camera. A user photo has no pose, so it is traced from a canonical R2N2-like camera:
azimuth 45, elevation 27.5 deg (the middle of R2N2's range), distance 2.8 = 0.8 * 1.75 / 0.5 (R2N2's mean
distance ratio in our unit-sphere frame), 49.13 deg field of view. Its depth map shows the reconstruction's
uncertainty from that fixed viewpoint, not aligned with the photo. So does a render whose views.npz cannot
be read, with a warning naming the file: the camera only places the depth map, the shape does not depend on it.
"""

from __future__ import annotations

import logging
import zipfile
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from torch import Tensor

from ushape import atomic
from ushape.data.cameras import R2N2_FOV_DEG, look_at
from ushape.data.layout import VIEWS_FILE
from ushape.fusion.rules import FusedCode
from ushape.propagation.depth_implicit import depth_stats
from ushape.propagation.monte_carlo import sample_codes
from ushape.propagation.sphere_tracing import DepthStats
from ushape.reconstruction.figures import depth_figure
from ushape.reconstruction.predictor import Predictor
from ushape.reconstruction.settings import ReconstructionSettings

log = logging.getLogger(__name__)

CANONICAL_CAMERA = {"azimuth_deg": 45.0, "elevation_deg": 27.5, "distance": 2.8, "fov_deg": R2N2_FOV_DEG}


def view_camera(path: Path, size: int) -> tuple[np.ndarray, np.ndarray, str]:
    """(K [3,3] for a size x size image, world_to_cam [4,4], "render" | "canonical") for one input image."""
    views = path.parent / VIEWS_FILE
    if views.is_file() and path.stem.isdigit():
        try:
            with np.load(views) as cams:
                view = int(path.stem)
                if view < len(cams["K"]):
                    K = cams["K"][view].astype(np.float64)
                    render_size = 2.0 * K[0, 2]  # the principal point is the image centre
                    scale = np.diag([size / render_size, size / render_size, 1.0])
                    return scale @ K, cams["world_to_cam"][view].astype(np.float64), "render"
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as err:
            # Only the depth map needs the camera: the shape is the same, seen from the canonical view.
            log.warning(
                "camera file %s of %s cannot be read (%s: %s): its depth map is traced from the canonical "
                "camera instead; re-render the view or delete the file",
                views,
                path,
                type(err).__name__,
                err,
            )
    c = CANONICAL_CAMERA
    K, w2c = look_at(c["azimuth_deg"], c["elevation_deg"], c["distance"], c["fov_deg"], size)
    return K, w2c, "canonical"


def depth_maps(
    predictor: Predictor,
    fused: FusedCode,
    cameras: Sequence[tuple[np.ndarray, np.ndarray, str]],  # view_camera(path, settings.depth_size) per view
    settings: ReconstructionSettings,
    generator: torch.Generator,
    bf16: bool = False,
) -> list[DepthStats]:
    """Per view: depth mean/std [S, S] of the fused Gaussian's surface along the view's camera.

    settings.depth_method "implicit" traces the mean code for all views at once and differentiates the hit
    depth (depth_implicit); "mc" traces M = settings.depth_codes codes drawn once from the fused Gaussian
    (the same codes for every view).
    """
    mc = settings.depth_method == "mc"
    codes = sample_codes(fused.mu, fused.var, settings.depth_codes, generator) if mc else None
    size = settings.depth_size
    return depth_stats(
        predictor.decoder,
        fused.mu,
        fused.var,
        [c[:2] for c in cameras],
        (size, size),
        settings.depth_method,
        codes,
        settings.depth_steps,
        bf16,
    )


def write_depth_maps(
    views: Sequence[DepthStats],
    images: Tensor,
    cameras: Sequence[tuple[np.ndarray, np.ndarray, str]],
    out_dir: Path,
    settings: ReconstructionSettings,
) -> list[dict[str, Any]]:
    """depth_<i>.npz (mean, std, hit_rate, K, world_to_cam) and depth_<i>.png per view; their summary records."""
    records = []
    for i, ((K, w2c, camera), stats) in enumerate(zip(cameras, views)):
        npz, png = out_dir / f"depth_{i:02d}.npz", out_dir / f"depth_{i:02d}.png"
        atomic.save_npz(
            npz, mean=stats.mean.numpy(), std=stats.std.numpy(), hit_rate=stats.hit_rate.numpy(), K=K, world_to_cam=w2c
        )
        depth_figure(images[i], stats, png, f"view {i} ({camera} camera, {settings.depth_method})")
        hit = stats.hit_rate > 0
        records.append(
            {
                "camera": camera,
                "method": settings.depth_method,
                "codes": settings.depth_codes if settings.depth_method == "mc" else None,
                "npz": str(npz),
                "png": str(png),
                "mean_depth_std": float(stats.std[hit].mean()) if hit.any() else None,
                "hit_pixels": int(hit.sum()),
            }
        )
    return records
