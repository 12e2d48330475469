"""First-order (linearised) propagation: var_s = J Sigma J^T with J = ds/dz at the mean code.

Sigma is diag(var) for a var [D] or the full covariance var [D, D] (`latent_variance`).
"""

from __future__ import annotations

import torch
from torch import Tensor

from ushape.decoder.folded import fold_code
from ushape.decoder.latent_gaussian import covariance_factor, is_full_covariance
from ushape.decoder.query import (
    Decoder,
    check_chunk,
    check_code_size,
    check_latent_gaussian,
    check_points,
    decoder_autocast,
    frozen,
    output_dtype,
)
from ushape.mesh.extraction import DEFAULT_CHUNK


def latent_variance(
    jacobian: Tensor,  # [P, D]
    var: Tensor,  # [D] diagonal, or [D, D] full covariance
) -> Tensor:  # [P]
    """First-order variance of P outputs, row by row J_p Sigma J_p^T: sum_d J_pd^2 var_d for a diagonal var.

    A full covariance goes through its square root L (`covariance_factor`): ||J_p L||^2, one [P, D] x
    [D, D] product and never a [P, D, D] tensor. It is >= 0 by construction and keeps its relative
    accuracy where the posterior is far narrower along J_p than its largest variance (the product
    (J Sigma * J).sum(-1) loses it there, by float32 rounding of the large terms).
    """
    if not is_full_covariance(var):
        return jacobian.square() @ var
    return (jacobian @ covariance_factor(var).to(jacobian.dtype)).square().sum(-1)


def sdf_gradients(
    decoder: Decoder,
    z: Tensor,  # [D]
    points: Tensor,  # [P, 3]
    with_xyz: bool = False,
    bf16: bool = False,
) -> tuple[Tensor, Tensor, Tensor | None]:
    """SDF f(x_p, z) [P], ds_p/dz [P, D] and (with_xyz) ds_p/dx [P, 3], in one forward/backward, by autograd.

    Each point gets its own copy of z as a leaf, so the gradient of sum_p s_p w.r.t. that [P, D]
    leaf holds every point's Jacobian row (a point's SDF depends only on its own copy and its own x).
    A decoder that ignores the code (or space) has no graph to it: that derivative is 0.
    Call inside `frozen(decoder)` so no parameter gradients are built. `FoldedDecoder` computes the
    same for a DeepSDF network without autograd.
    """
    z_per_point = z.detach().expand(points.shape[0], z.shape[0]).clone().requires_grad_(True)
    xyz = points.detach().clone().requires_grad_(with_xyz)
    leaves = (z_per_point, xyz) if with_xyz else (z_per_point,)
    with torch.enable_grad():
        with decoder_autocast(points.device, bf16):
            sdf = decoder(xyz, z_per_point)
        grads = torch.autograd.grad(sdf.sum(), leaves, allow_unused=True)
    grads = [torch.zeros_like(leaf) if g is None else g.detach() for g, leaf in zip(grads, leaves)]
    return sdf.detach(), grads[0], grads[1] if with_xyz else None


def latent_jacobian(
    decoder: Decoder,
    z: Tensor,  # [D]
    points: Tensor,  # [P, 3]
    bf16: bool = False,
) -> tuple[Tensor, Tensor]:
    """SDF f(x_p, z) [P] and its gradient w.r.t. the latent code, ds_p/dz [P, D] (see `sdf_gradients`)."""
    sdf, jacobian, _ = sdf_gradients(decoder, z, points, bf16=bf16)
    return sdf, jacobian


def propagate_linearised(
    decoder: Decoder,
    mu: Tensor,  # [D]
    var: Tensor,  # [D] or [D, D]
    points: Tensor,  # [P, 3]
    chunk: int = DEFAULT_CHUNK,
    bf16: bool = False,
) -> tuple[Tensor, Tensor]:
    """SDF mean f(x, mu) [P] and first-order variance J Sigma J^T [P] at points (`latent_variance`).

    Exact for a decoder linear in z; for the real decoder it is the local (delta-method)
    approximation, good while the latent spread stays where the decoder is near-linear.
    Costs about one forward and one backward pass per chunk, however many samples MC would need;
    a DeepSDFDecoder's backward is the hand-written one of `fold_code` (no autograd; folded in bf16 under bf16).
    """
    check_latent_gaussian(mu, var)
    check_code_size(decoder, mu.shape[0])
    check_points(points)
    check_chunk(chunk)
    dtype = output_dtype(points, bf16)
    mean = torch.empty(points.shape[0], dtype=dtype, device=points.device)
    variance = torch.empty_like(mean)
    with frozen(decoder):
        folded = fold_code(decoder, mu, bf16)
        for start in range(0, points.shape[0], chunk):
            block = points[start : start + chunk]
            stop = start + block.shape[0]
            if folded is None:
                sdf, jacobian = latent_jacobian(decoder, mu, block, bf16)
            else:
                with torch.no_grad():
                    sdf, jacobian = folded.sdf_and_jacobian(block)
            mean[start:stop] = sdf.to(dtype)
            variance[start:stop] = latent_variance(jacobian.to(dtype), var.to(dtype))
    return mean, variance
