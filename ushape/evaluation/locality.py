"""Where on the object the predicted uncertainty sits: on the parts a view hides or crops away?

For each test view with its camera, points sampled on the ground-truth surface are split by what the
encoder was shown:
  visible / hidden    the first ray hit from the camera is the point itself / something else
  kept / away         visible points inside / outside the crop window of the view's corrupted copy
                      (the same crop the corrupted-views protocol uses, from `augment.view_seed`)
The SDF std at every point is propagated (linearised) from the view's latent Gaussian, once for the
clean image and once for the cropped one, and compared as ratios of medians:
  hidden_over_visible     clean input: std on hidden points / std on visible points
  away_over_kept          std on the points the crop removes / std on the points it keeps, for the clean
                          input and for the cropped one
  crop_shift              cropped / clean away_over_kept: the decoder's own part sensitivity (thin legs move
                          more with the code than a seat) divides out; > 1: cropping moved uncertainty onto
                          the removed part
  std_gain                mean std with the cropped input / with the clean one (> 1: less sure overall)
  error_...               the same ratios of the error |f(x, mu)| at the points (0 on a perfect surface):
                          where the prediction really is worse, which a calibrated std should follow
  fused_hidden/visible    median std after Bayesian fusion of all the shape's views / single view, on the
                          view's hidden and visible points (fusion should shrink the hidden part's std more)
Ground-truth points rather than the reconstruction's vertices keep the point sets the same for both
inputs, so the two std fields are compared on the same parts. A Gaussian with a full covariance [D, D]
(a reconstruction method's, refined on the view) is propagated as it is.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import torch
import trimesh
from PIL import Image
from torch import Tensor
from tqdm.auto import tqdm

from ushape.data.augment import corrupted_box, view_seed
from ushape.data.cameras import camera_centre, project
from ushape.data.layout import WorldIndex
from ushape.evaluation.protocols import EncoderSpec
from ushape.evaluation.views import Encodings, Estimate, ViewKey
from ushape.fusion.rules import fuse_bayesian
from ushape.mesh.visibility import median_ratio, visible_points
from ushape.propagation import propagate


@dataclass(frozen=True)
class ViewParts:
    """Surface points of one shape split by one view: hidden [P], and of the visible ones kept / away [P]."""

    hidden: np.ndarray
    kept: np.ndarray
    away: np.ndarray


def surface_points(
    world: WorldIndex, shape_id: str, n_points: int, seed: int = 0
) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The shape's ground-truth mesh and a repeatable sample of n_points [P, 3] on its surface."""
    path = world.mesh_path(shape_id)
    if not path.is_file():
        raise FileNotFoundError(f"no ground-truth mesh {path}: the world folder is incomplete; rebuild it")
    mesh = trimesh.load(path, force="mesh", process=False)
    points, _ = trimesh.sample.sample_surface(mesh, n_points, seed=seed + zlib.crc32(shape_id.encode()))
    return mesh, np.asarray(points, dtype=np.float64)


def has_cameras(world: WorldIndex, shape_ids: Sequence[str]) -> bool:
    """Whether every shape's renders come with their cameras (views.npz); real photos may not."""
    return all(world.views_path(s).is_file() for s in shape_ids)


def render_cameras(world: WorldIndex, shape_id: str) -> tuple[np.ndarray, np.ndarray]:
    """Intrinsics [V, 3, 3] at the render size and world_to_cam [V, 4, 4] of a shape's views."""
    path = world.views_path(shape_id)
    if not path.is_file():
        raise FileNotFoundError(f"no cameras {path} for {shape_id}'s renders: the world folder is incomplete")
    with np.load(path) as cams:
        return cams["K"].astype(np.float64), cams["world_to_cam"].astype(np.float64)


def split_points(
    mesh: trimesh.Trimesh,
    points: np.ndarray,  # [P, 3]
    K: np.ndarray,  # [3, 3]
    world_to_cam: np.ndarray,  # [4, 4]
    box: tuple[int, int, int, int],  # (top, left, h, w) in pixels of the image K belongs to
) -> ViewParts:
    """Which points the camera sees, and which of those fall inside the crop box."""
    visible = visible_points(mesh, points, camera_centre(world_to_cam))
    uv, _ = project(points, K, world_to_cam)
    top, left, h, w = box
    inside = (uv[:, 0] >= left) & (uv[:, 0] < left + w) & (uv[:, 1] >= top) & (uv[:, 1] < top + h)
    return ViewParts(hidden=~visible, kept=visible & inside, away=visible & ~inside)


def point_stats(decoder, mu: Tensor, var: Tensor, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """At ground-truth surface points [P, 3]: the error |f(x, mu)| [P] and the linearised SDF std [P] of the
    Gaussian (mu [D], var [D] or [D, D])."""
    xyz = torch.as_tensor(points, dtype=torch.float32)
    mean, variance = propagate(decoder, mu.float(), var.float(), xyz, "linearised")
    return mean.abs().numpy(), variance.clamp_min(0).sqrt().numpy()


def _shift(values_clean: np.ndarray, values_crop: np.ndarray, parts: ViewParts) -> tuple:
    """(away/kept with the clean input, away/kept with the cropped input, their quotient); None where undefined."""
    clean = median_ratio(values_clean, parts.away, parts.kept)
    crop = median_ratio(values_crop, parts.away, parts.kept)
    return clean, crop, None if clean is None or crop is None else crop / clean


def view_record(
    parts: ViewParts, clean: tuple[np.ndarray, np.ndarray], crop: tuple[np.ndarray, np.ndarray], std_fused: np.ndarray
) -> dict:
    """The ratios of the module docstring for one view (None where a point set is empty).

    clean and crop are (error [P], std [P]) from `point_stats`. The same ratios of the error say where
    the prediction really is worse: the std ratios should follow them.
    """
    (err_clean, std_clean), (err_crop, std_crop) = clean, crop
    away_clean, away_crop, shift = _shift(std_clean, std_crop, parts)
    _, _, error_shift = _shift(err_clean, err_crop, parts)
    visible = ~parts.hidden
    return {
        "n_visible": int(visible.sum()),
        "n_away": int(parts.away.sum()),
        "hidden_over_visible": median_ratio(std_clean, parts.hidden, visible),
        "error_hidden_over_visible": median_ratio(err_clean, parts.hidden, visible),
        "away_over_kept_clean": away_clean,
        "away_over_kept_cropped": away_crop,
        "crop_shift": shift,
        "error_crop_shift": error_shift,
        "std_gain": float(std_crop.mean() / std_clean.mean()) if std_clean.mean() > 0 else None,
        "error_gain": float(err_crop.mean() / err_clean.mean()) if err_clean.mean() > 0 else None,
        "fused_hidden": median_ratio(std_fused, parts.hidden, parts.hidden, std_clean),
        "fused_visible": median_ratio(std_fused, visible, visible, std_clean),
    }


def locality_records(
    spec: EncoderSpec,
    clean: Encodings,
    cropped: Encodings,
    decoder,
    world: WorldIndex,
    min_scale: float,
    seed: int = 0,
    n_points: int = 2048,
    views_per_shape: int | None = None,
    fuse: Callable[[str], Estimate] | None = None,
) -> list[dict]:
    """One record per test view (of a probabilistic encoder): where its uncertainty sits (module docstring).

    fuse: shape id -> the Gaussian of all its views fused (default: the Bayesian rule on `clean`'s views of it).
    """
    if not spec.probabilistic:
        return []
    if clean.keys != cropped.keys:
        raise ValueError("clean and cropped encodings must hold the same views in the same order")
    by_shape: dict[str, list[ViewKey]] = {}
    for key in clean.keys:
        by_shape.setdefault(key.shape_id, []).append(key)
    records = []
    for shape_id, keys in tqdm(by_shape.items(), desc=f"{spec.name} locality", leave=False):
        mesh, points = surface_points(world, shape_id, n_points, seed)
        Ks, w2cs = render_cameras(world, shape_id)
        fused = fuse(shape_id) if fuse is not None else fuse_bayesian(*clean.select(keys))
        _, std_fused = point_stats(decoder, fused.mu, fused.var, points)
        for key in keys[:views_per_shape]:
            with Image.open(world.image_path(key.shape_id, key.view)) as image:  # reads the header only
                width, height = image.size
            box = corrupted_box(height, width, min_scale, view_seed(seed, key.shape_id, key.view))
            parts = split_points(mesh, points, Ks[key.view], w2cs[key.view], box)
            (mu_c, var_c), (mu_x, var_x) = clean.select([key]), cropped.select([key])
            clean_stats = point_stats(decoder, mu_c[0], var_c[0], points)
            crop_stats = point_stats(decoder, mu_x[0], var_x[0], points)
            records.append(
                {
                    "encoder": spec.name,
                    "label": spec.label,
                    "min_scale": float(min_scale),
                    "shape_id": shape_id,
                    "view": key.view,
                    **view_record(parts, clean_stats, crop_stats, std_fused),
                }
            )
    return records


def summarise_locality(records: Sequence[dict], min_away: float = 0.05) -> list[dict]:
    """Per (encoder, min scale): medians of the per-view ratios, and how often each exceeds 1.

    The crop ratios count only views whose crop removes at least `min_away` of the visible points.
    """
    groups: dict[tuple[str, float], list[dict]] = {}
    for r in records:
        groups.setdefault((r["encoder"], r["min_scale"]), []).append(r)
    rows = []
    for (encoder, scale), group in groups.items():
        cropped = [r for r in group if r["n_visible"] and r["n_away"] >= min_away * r["n_visible"]]
        row = {
            "encoder": encoder,
            "label": group[0]["label"],
            "min_scale": scale,
            "n_views": len(group),
            "n_cropped_views": len(cropped),
        }
        for name, pool in (
            ("hidden_over_visible", group),
            ("error_hidden_over_visible", group),
            ("away_over_kept_clean", cropped),
            ("away_over_kept_cropped", cropped),
            ("crop_shift", cropped),
            ("error_crop_shift", cropped),
            ("std_gain", group),
            ("error_gain", group),
            ("fused_hidden", group),
            ("fused_visible", group),
        ):
            values = np.array([r[name] for r in pool if r[name] is not None], dtype=np.float64)
            row[name] = float(np.median(values)) if len(values) else None
            row[f"{name}_above_1"] = float(np.mean(values > 1)) if len(values) else None
        rows.append(row)
    return rows
