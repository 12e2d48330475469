"""Expected depth and its spread per pixel by sphere tracing the SDFs of M sampled latent codes.

The paper's supplementary Fig. S1: draw M codes from the fused Gaussian, sphere-trace each code's
SDF along every pixel ray (batched over codes and pixels), and report per pixel the mean and the
standard deviation of the depth over the codes whose ray hit the surface. Depth is the camera-frame
z of the hit (OpenCV, as `ushape.data.rendering` writes it); rays are only traced inside the
decoder's domain, the cube [-bound, bound]^3. `depth_implicit` gets the std from one trace of the
mean code instead (reconstruct.py's default); this Monte Carlo method stays as `--depth-method mc`.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np
import torch
from torch import Tensor

from ushape.data.rendering import pixel_rays
from ushape.decoder.query import decoder_autocast, frozen

BatchSDF = Callable[[Tensor, Tensor], Tensor]  # (points [N, 3], code index [N]) -> sdf [N]


class DepthStats(NamedTuple):
    """Per-pixel depth statistics over M codes; NaN where no code's ray hit."""

    mean: Tensor  # [H, W]
    std: Tensor  # [H, W]
    hit_rate: Tensor  # [H, W] fraction of the M codes whose ray hit


def ray_box(origins: Tensor, directions: Tensor, bound: float) -> tuple[Tensor, Tensor]:
    """Entry and exit ray parameters [P] of rays o + t d with the cube [-bound, bound]^3 (exit < entry: miss)."""
    inv = 1.0 / torch.where(directions.abs() < 1e-12, torch.full_like(directions, 1e-12), directions)
    t0, t1 = (-bound - origins) * inv, (bound - origins) * inv
    near = torch.minimum(t0, t1).amax(dim=-1).clamp_min(0.0)
    far = torch.maximum(t0, t1).amin(dim=-1)
    return near, far


def sphere_trace(
    sdf: BatchSDF,
    origins: Tensor,  # [P, 3]
    directions: Tensor,  # [P, 3], any length (parameter t is along d)
    n_codes: int,
    steps: int = 50,
    eps: float = 2e-3,
    bound: float = 1.0,
) -> tuple[Tensor, Tensor]:
    """Ray parameters t [M, P] of the first surface hit per code and ray, and hit flags [M, P]."""
    norm = directions.norm(dim=-1)
    near, far = ray_box(origins, directions, bound)
    t = near.expand(n_codes, -1).clone()
    active = (far > near).expand(n_codes, -1).clone()
    hit = torch.zeros_like(active)
    for _ in range(steps):
        # Only rays still marching are evaluated: most finish or leave the cube within a few steps.
        code, pixel = active.nonzero(as_tuple=True)
        if code.numel() == 0:
            break
        t_now = t[code, pixel]
        values = sdf(origins[pixel] + t_now[:, None] * directions[pixel], code)
        converged = values.abs() < eps
        hit[code[converged], pixel[converged]] = True
        # A ray that starts inside the surface (negative SDF) is stepped back onto it as well.
        t_next = torch.where(converged, t_now, t_now + values / norm[pixel])
        t[code, pixel] = t_next
        active[code, pixel] = ~converged & (t_next <= far[pixel]) & (t_next >= near[pixel] - eps)
    return t, hit


def codes_sdf(decoder: torch.nn.Module, codes: Tensor, bf16: bool = False) -> BatchSDF:  # codes [M, D]
    """(points [N, 3], code index [N]) -> sdf [N] (float32) of each point under its code, without gradients."""

    def sdf(points: Tensor, which: Tensor) -> Tensor:
        with torch.no_grad(), decoder_autocast(points.device, bf16):
            return decoder(points, codes[which]).float()

    return sdf


def depth_statistics(depth: Tensor, hit: Tensor, image_hw: tuple[int, int]) -> DepthStats:
    """Mean/std over the codes that hit of depth [M, P] (hit [M, P]) -> DepthStats of [H, W] maps."""
    count = hit.sum(dim=0)
    safe = count.clamp_min(1)
    mean = torch.where(hit, depth, 0.0).sum(dim=0) / safe
    var = torch.where(hit, (depth - mean).square(), 0.0).sum(dim=0) / safe
    nan = torch.full_like(mean, float("nan"))
    mean, std = torch.where(count > 0, mean, nan), torch.where(count > 0, var.sqrt(), nan)
    return DepthStats(mean.reshape(image_hw), std.reshape(image_hw), (count / depth.shape[0]).reshape(image_hw))


def camera_rays(
    K: np.ndarray,  # [3, 3] for an image of image_hw
    world_to_cam: np.ndarray,  # [4, 4]
    image_hw: tuple[int, int],
    steps: int,
    eps: float,
) -> tuple[Tensor, Tensor]:
    """float32 world ray origins and directions [H*W, 3] of every pixel (camera-z component 1), inputs checked."""
    K, world_to_cam = np.asarray(K, dtype=np.float64), np.asarray(world_to_cam, dtype=np.float64)
    if K.shape != (3, 3) or world_to_cam.shape != (4, 4):
        raise ValueError(f"expected K [3, 3] and world_to_cam [4, 4], got {K.shape} and {world_to_cam.shape}")
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ValueError(f"steps (sphere-tracing iterations) must be a positive integer, got {steps!r}")
    if not eps > 0:
        raise ValueError(f"eps (the |sdf| that counts as a hit) must be positive, got {eps!r}")
    return tuple(torch.as_tensor(a, dtype=torch.float32) for a in pixel_rays(K, world_to_cam, image_hw))


def depth_uncertainty(
    decoder: torch.nn.Module,
    codes: Tensor,  # [M, D]
    K: np.ndarray,  # [3, 3] for an image of image_hw
    world_to_cam: np.ndarray,  # [4, 4]
    image_hw: tuple[int, int],
    steps: int = 50,
    eps: float = 2e-3,
    bf16: bool = False,
) -> DepthStats:
    """Per-pixel depth mean and std [H, W] over the M codes' sphere-traced surfaces (decoder under bf16 if asked)."""
    if codes.ndim != 2 or codes.shape[0] < 1:
        raise ValueError(f"codes must be M >= 1 latent codes [M, D], got shape {tuple(codes.shape)}")
    origins, directions = camera_rays(K, world_to_cam, image_hw, steps, eps)
    with frozen(decoder):
        sdf = codes_sdf(decoder, codes.float(), bf16)
        t, hit = sphere_trace(sdf, origins, directions, codes.shape[0], steps, eps)
    # pixel_rays' directions have camera-z component 1, so the ray parameter t is the depth itself.
    return depth_statistics(t, hit, image_hw)
