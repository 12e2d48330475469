"""Is the predicted depth std calibrated? Depth std against the true depth error on held-out renders (Table D).

Each test view's latent Gaussian (mu, var) gives, along that view's own camera, a per-pixel depth mean
and std as reconstruct.py computes them ("implicit": one trace of the mean code and its first-order
sensitivity; "mc": M sampled codes traced). The truth is the ground-truth mesh's depth along the same
pixel rays: the world's stored depth (views.npz) when it has the evaluated size, else the mesh rendered
again at that size. Over the pixels where both the prediction and the truth hit (for Monte Carlo: more
than half of the codes), the z-scores (true - predicted) / std give the mean |error|, the mean std,
their rank correlation per pixel, the coverage of the 68 % and 95 % intervals and the calibration
error of `calibration.py` (the curve over probability levels, as for the latent and SDF spaces).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch
import trimesh
from torch import Tensor
from tqdm.auto import tqdm

from ushape.data.augment import view_seed
from ushape.data.layout import WorldIndex
from ushape.data.rendering import RayCaster, render_mesh
from ushape.encoder.latent_metrics import spearman_correlation
from ushape.evaluation.locality import render_cameras
from ushape.evaluation.protocols import EncoderSpec
from ushape.evaluation.views import Encodings
from ushape.metrics.calibration import calibration_curve, calibration_error, two_sided_quantile
from ushape.propagation.depth_implicit import depth_stats
from ushape.propagation.monte_carlo import sample_codes

COVERAGE_LEVELS = {"coverage_68": 0.68, "coverage_95": 0.95}
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DepthTarget:
    """One view to score: its latent Gaussian and the true depth along its camera's pixel rays."""

    mu: Tensor  # [D]
    var: Tensor  # [D], or [D, D] (a full covariance)
    depth: np.ndarray  # [H, W] true camera-z depth, 0 where the ray misses
    K: np.ndarray  # [3, 3] for an image of depth's size
    world_to_cam: np.ndarray  # [4, 4]


def view_depth_errors(
    decoder, target: DepthTarget, method: str, n_codes: int = 10, steps: int = 50, seed: int = 0
) -> tuple[Tensor, Tensor]:
    """(signed error true - predicted mean [N], predicted std [N]) at the pixels where both hit."""
    hw = tuple(target.depth.shape)
    codes = None
    if method == "mc":
        codes = sample_codes(target.mu.float(), target.var.float(), n_codes, torch.Generator().manual_seed(seed))
    stats = depth_stats(decoder, target.mu, target.var, [(target.K, target.world_to_cam)], hw, method, codes, steps)[0]
    truth = torch.as_tensor(np.asarray(target.depth, dtype=np.float32))
    both = (stats.hit_rate > 0.5) & torch.isfinite(stats.std) & (truth > 0)
    return (truth - stats.mean)[both], stats.std[both]


def depth_calibration(
    error: Tensor,  # [N] true - predicted depth
    std: Tensor,  # [N] predicted depth std
    n_levels: int = 20,
) -> tuple[dict[str, float], tuple[Tensor, Tensor]]:
    """Scores of depth predictions N(mean, std^2) against the truth, and the calibration curve (p, freq).

    mean_abs_error, mean_std, rank_corr (Spearman of |error| and std over the pixels), coverage_68 and
    coverage_95 (fraction with |error| <= Q(p) std), calibration_error, mean_z, rms_z and median_abs_z of
    the z-scores error / std (0, 1 and 0.674 when calibrated; pixels with std 0 left out), n_pixels. RMS z
    is dominated by the few pixels where prediction and truth hit different parts; the median is not.
    """
    error, std = torch.as_tensor(error, dtype=torch.float64), torch.as_tensor(std, dtype=torch.float64)
    p, freq = calibration_curve(error.abs(), std, n_levels)  # checks shapes, emptiness, NaN and signs
    spread = std > 0
    z = error[spread] / std[spread]
    scores = {
        "mean_abs_error": float(error.abs().mean()),
        "mean_std": float(std.mean()),
        "rank_corr": float(spearman_correlation(error.abs(), std)) if len(error) > 1 else math.nan,
        **{
            name: float(
                (error.abs() <= two_sided_quantile(torch.tensor(level, dtype=torch.float64)) * std).double().mean()
            )
            for name, level in COVERAGE_LEVELS.items()
        },
        "calibration_error": calibration_error(p, freq),
        "mean_z": float(z.mean()) if len(z) else math.nan,
        "rms_z": float(z.square().mean().sqrt()) if len(z) else math.nan,
        "median_abs_z": float(z.abs().median()) if len(z) else math.nan,
        "n_pixels": int(error.numel()),
    }
    return scores, (p, freq)


def true_depths(world: WorldIndex, shape_id: str, views: Sequence[int], size: int) -> list[tuple]:
    """(true depth [H, W] (0: miss), K [3, 3], world_to_cam [4, 4]) of a shape's views at `size` pixels
    along the longer side: the stored depth when views.npz has it at that size, else the mesh rendered."""
    Ks, w2cs = render_cameras(world, shape_id)
    with np.load(world.views_path(shape_id)) as cams:
        stored = cams["depth"] if "depth" in cams.files else None
    caster = None
    out = []
    for view in views:
        render_hw = (2.0 * Ks[view][1, 2], 2.0 * Ks[view][0, 2])  # the principal point is the image centre
        scale = size / max(render_hw)
        hw = (round(render_hw[0] * scale), round(render_hw[1] * scale))
        K = np.diag([scale, scale, 1.0]) @ Ks[view]
        if stored is not None and stored.shape[1:] == hw:
            out.append((stored[view].astype(np.float32), K, w2cs[view]))
            continue
        if caster is None:
            mesh_path = world.mesh_path(shape_id)
            if not mesh_path.is_file():
                raise FileNotFoundError(f"no ground-truth mesh {mesh_path}: the world folder is incomplete")
            caster = RayCaster(trimesh.load(mesh_path, force="mesh", process=False))
        out.append((render_mesh(caster, K, w2cs[view], hw)["depth"], K, w2cs[view]))
    return out


def depth_calibration_rows(
    spec: EncoderSpec,
    encodings: Encodings,
    decoder,
    world: WorldIndex,
    size: int = 48,
    methods: Sequence[str] = ("implicit", "mc"),
    n_codes: int = 10,
    steps: int = 50,
    views_per_shape: int | None = 2,
    n_levels: int = 20,
    seed: int = 0,
) -> tuple[list, dict]:
    """Table D's rows (one per depth method) and calibration curves for one probabilistic encoder's views."""
    if not spec.probabilistic:
        return [], {}
    encodings = encodings.first_views(views_per_shape)
    by_shape: dict[str, list[int]] = {}
    for i, key in enumerate(encodings.keys):
        by_shape.setdefault(key.shape_id, []).append(i)
    pools: dict[str, list[tuple[Tensor, Tensor]]] = {method: [] for method in methods}
    for shape_id, rows in tqdm(by_shape.items(), desc=f"{spec.name} depth calibration", leave=False):
        truths = true_depths(world, shape_id, [encodings.keys[i].view for i in rows], size)
        for i, (depth, K, w2c) in zip(rows, truths):
            target = DepthTarget(encodings.mu[i], encodings.var[i], depth, K, w2c)
            for method in methods:
                pools[method].append(
                    view_depth_errors(
                        decoder, target, method, n_codes, steps, view_seed(seed, shape_id, encodings.keys[i].view)
                    )
                )
    out, curves = [], {}
    for method, parts in pools.items():
        error, std = torch.cat([e for e, _ in parts]), torch.cat([s for _, s in parts])
        if error.numel() == 0:
            log.warning("Table D: no pixel where both %s's %s depth and the truth hit; row left out", spec.name, method)
            continue
        scores, curve = depth_calibration(error, std, n_levels)
        label = method if method != "mc" else f"mc M={n_codes}"
        out.append(
            {"encoder": spec.name, "label": spec.label, "method": label, "size": size, "n_views": len(parts), **scores}
        )
        curves[f"{spec.label} (depth, {label})"] = curve
    return out, curves
