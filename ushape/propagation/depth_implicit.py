"""Per-pixel depth std by implicit differentiation: one sphere trace of the mean code and one Jacobian.

At a pixel's hit x(t) = o + t d of the mean code's surface, s(x(t), z) = 0. Differentiating that
identity in z gives the depth's sensitivity to the code,

    dt/dz = -(ds/dz) / (ds/dx . d),

and the first-order (delta-method) depth variance (dt/dz) Sigma (dt/dz)^T (`latent_variance`), as
`ushape.propagation.linearised` does for the SDF. pixel_rays' directions have camera-z component 1,
so t is the depth. Exact where the depth is linear in the code (a plane whose offset is linear in
z); elsewhere good while the latent spread moves the surface little, i.e. away from silhouettes.

Grazing rays: as the ray turns tangent to the surface, ds/dx . d -> 0 and the first-order
sensitivity diverges (the true depth there jumps between this surface and whatever lies behind
it). The slope along the unit ray direction is therefore clamped to at least `min_cosine` times the
gradient's norm, i.e. rays are treated as meeting the surface at no more than acos(min_cosine)
(87 degrees for 0.05) from its normal; this caps the std at silhouette pixels, it does not fix it.

Monte Carlo (`sphere_tracing.depth_uncertainty`, M traces) stays the other method, "mc".
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
from torch import Tensor

from ushape.decoder.folded import fold_code
from ushape.decoder.query import Decoder, check_code_size, check_latent_gaussian, frozen
from ushape.encoder.latent_metrics import spearman_correlation
from ushape.mesh.extraction import DEFAULT_CHUNK
from ushape.propagation.linearised import latent_variance, sdf_gradients
from ushape.propagation.sphere_tracing import DepthStats, camera_rays, codes_sdf, depth_uncertainty, sphere_trace

DEPTH_METHODS = ("implicit", "mc")
MIN_COSINE = 0.05
Camera = tuple[np.ndarray, np.ndarray]  # (K [3, 3], world_to_cam [4, 4])


def depth_sensitivity(
    grad_z: Tensor,  # [P, D]
    grad_x: Tensor,  # [P, 3]
    directions: Tensor,  # [P, 3]
    min_cosine: float = MIN_COSINE,
) -> Tensor:  # [P, D]
    """dt/dz = -(ds/dz) / (ds/dx . d) per hit, with |ds/dx . d| >= min_cosine |ds/dx| |d| (grazing clamp)."""
    slope = (grad_x * directions).sum(dim=-1)  # ds/dt along the ray
    floor = min_cosine * grad_x.norm(dim=-1) * directions.norm(dim=-1)
    magnitude = torch.maximum(slope.abs(), floor).clamp_min(torch.finfo(slope.dtype).tiny)
    # A ray entering the surface from outside sees the SDF fall (ds/dt < 0); a clamped 0 slope keeps that sign.
    signed = torch.where(slope > 0, magnitude, -magnitude)
    return -grad_z / signed[:, None]


def depth_uncertainty_implicit_views(
    decoder: Decoder,
    mu: Tensor,  # [D]
    var: Tensor,  # [D] or [D, D] (a full covariance)
    cameras: Sequence[Camera],  # V x (K [3, 3] for an image of image_hw, world_to_cam [4, 4])
    image_hw: tuple[int, int],
    steps: int = 50,
    eps: float = 2e-3,
    min_cosine: float = MIN_COSINE,
    chunk: int = DEFAULT_CHUNK,
    bf16: bool = False,
) -> list[DepthStats]:
    """Per view, the depth of the mean code's surface and its first-order std [H, W]; hit_rate 1 (hit) or 0.

    Every view's rays are traced together: one decoder call per step serves all of them, which is
    what makes one trace of V views cheaper than V traces (most steps march only a few rays).
    bf16 traces in bf16 (a DeepSDFDecoder folded in bf16, another decoder under autocast); the gradients
    at the hits stay fp32.
    """
    check_latent_gaussian(mu, var)
    check_code_size(decoder, mu.shape[0])
    if not 0.0 <= min_cosine <= 1.0:
        raise ValueError(f"min_cosine must be in [0, 1], got {min_cosine!r}")
    if len(cameras) == 0:
        raise ValueError("no cameras: pass at least one (K, world_to_cam)")
    rays = [camera_rays(K, w2c, image_hw, steps, eps) for K, w2c in cameras]
    origins, directions = torch.cat([o for o, _ in rays]), torch.cat([d for _, d in rays])
    mu, var = mu.detach().float(), var.detach().float()
    with frozen(decoder), torch.no_grad():
        # A DeepSDFDecoder is traced and differentiated with the mean code folded in (no autograd).
        folded = fold_code(decoder, mu)
        traced = fold_code(decoder, mu, bf16=True) if bf16 and folded is not None else folded
        trace_sdf = codes_sdf(decoder, mu[None], bf16) if traced is None else (lambda points, _code: traced.sdf(points))
        t, hit = sphere_trace(trace_sdf, origins, directions, 1, steps, eps)
        t, hit = t[0], hit[0]
        pixels = hit.nonzero().squeeze(1)
        variance = torch.empty(pixels.shape[0])
        for start in range(0, pixels.shape[0], chunk):
            ray = pixels[start : start + chunk]
            points = origins[ray] + t[ray, None] * directions[ray]
            if folded is None:
                _, grad_z, grad_x = sdf_gradients(decoder, mu, points, with_xyz=True)
            else:
                _, grad_z, grad_x = folded.sdf_and_gradients(points)
            sensitivity = depth_sensitivity(grad_z.float(), grad_x.float(), directions[ray], min_cosine)
            variance[start : start + ray.shape[0]] = latent_variance(sensitivity, var)
    mean = torch.where(hit, t, torch.full_like(t, float("nan")))
    std = torch.full_like(t, float("nan"))
    std[pixels] = variance.sqrt()
    maps = (m.reshape(len(cameras), *image_hw) for m in (mean, std, hit.float()))
    return [DepthStats(*view) for view in zip(*maps)]


def depth_uncertainty_implicit(
    decoder: Decoder,
    mu: Tensor,  # [D]
    var: Tensor,  # [D] or [D, D] (a full covariance)
    K: np.ndarray,  # [3, 3] for an image of image_hw
    world_to_cam: np.ndarray,  # [4, 4]
    image_hw: tuple[int, int],
    steps: int = 50,
    eps: float = 2e-3,
    min_cosine: float = MIN_COSINE,
    chunk: int = DEFAULT_CHUNK,
) -> DepthStats:
    """Depth of the mean code's surface and its first-order std [H, W] for one camera (see the _views form)."""
    return depth_uncertainty_implicit_views(
        decoder, mu, var, [(K, world_to_cam)], image_hw, steps, eps, min_cosine, chunk
    )[0]


def depth_stats(
    decoder: Decoder,
    mu: Tensor,  # [D]
    var: Tensor,  # [D] or [D, D] (a full covariance)
    cameras: Sequence[Camera],  # V x (K [3, 3], world_to_cam [4, 4])
    image_hw: tuple[int, int],
    method: str = "implicit",
    codes: Tensor | None = None,  # [M, D] drawn from N(mu, var), for method "mc"
    steps: int = 50,
    bf16: bool = False,
) -> list[DepthStats]:
    """Depth mean/std [H, W] per camera by either method: "implicit" (mu, var; one trace for all views)
    or "mc" (the codes, traced view by view)."""
    if method == "implicit":
        return depth_uncertainty_implicit_views(decoder, mu, var, cameras, image_hw, steps, bf16=bf16)
    if method == "mc":
        if codes is None:
            raise ValueError("depth method 'mc' traces sampled codes: pass codes [M, D] (see sample_codes)")
        return [depth_uncertainty(decoder, codes, K, w2c, image_hw, steps, bf16=bf16) for K, w2c in cameras]
    raise ValueError(f"depth method must be one of {DEPTH_METHODS}, got {method!r}")


def std_agreement(implicit: DepthStats, mc: DepthStats) -> dict[str, float | int]:
    """Median of std implicit / MC, and Pearson and Spearman correlations of the two std maps, over pixels
    hit by the mean code and by every sampled code (partial MC hits are silhouettes, where neither std
    means much). Pearson is swayed by the few pixels where one code reaches another part of the surface;
    the rank correlation is not."""
    both = (implicit.hit_rate > 0) & (mc.hit_rate == 1) & (mc.std > 0)
    a, b = implicit.std[both].double(), mc.std[both].double()
    n = int(both.sum())
    ratio = float((a / b).median()) if n else float("nan")
    varied = n > 1 and bool(a.std() > 0) and bool(b.std() > 0)  # a constant map has no correlation
    pearson = float(torch.corrcoef(torch.stack([a, b]))[0, 1]) if varied else float("nan")
    spearman = float(spearman_correlation(a, b)) if varied else float("nan")
    return {"median_ratio": ratio, "pearson": pearson, "spearman": spearman, "pixels": n}
