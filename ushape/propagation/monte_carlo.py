"""Monte Carlo propagation (paper Sec. 3.2): sample codes, decode them all, take sample statistics."""

from __future__ import annotations

import torch
from torch import Tensor

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


def sample_codes(mu: Tensor, var: Tensor, n_samples: int, generator: torch.Generator | None = None) -> Tensor:
    """M codes z_m ~ N(mu, Sigma) in latent space: mu [D], var [D] (Sigma = diag(var)) or [D, D] -> [M, D].

    A full covariance maps the same standard normal draws through its square root L (z = mu + L eps,
    `covariance_factor`), so a diagonal [D, D] covariance gives exactly the codes of its [D] form.
    """
    eps = torch.randn(n_samples, mu.shape[-1], generator=generator, dtype=mu.dtype, device=mu.device)
    if is_full_covariance(var):
        return mu + eps @ covariance_factor(var).to(mu.dtype).T
    return mu + var.sqrt() * eps


def propagate_mc(
    decoder: Decoder,
    mu: Tensor,  # [D]
    var: Tensor,  # [D] or [D, D]
    points: Tensor,  # [P, 3]
    n_samples: int = 10,
    generator: torch.Generator | None = None,
    chunk: int = 512,
    bf16: bool = False,
    return_samples: bool = False,
) -> tuple[Tensor, Tensor] | tuple[Tensor, Tensor, Tensor]:
    """SDF sample mean [P] and unbiased sample variance [P] (1/(M-1), paper Eq. sdf_net) at points.

    All M codes meet each chunk of points in one decoder pass (codes [M, 1, D] against points
    [1, Pc, 3]), so a pass holds M * chunk rows; a few thousand rows per pass ran fastest
    on CPU. With return_samples, also returns the SDF samples [M, P]. Under bf16 the decoder's outputs
    carry ~3 significant digits, which limits how small a variance can be resolved (relative to the SDF's magnitude).
    """
    if isinstance(n_samples, bool) or not isinstance(n_samples, int) or n_samples < 2:
        raise ValueError(
            f"n_samples must be an integer >= 2: the unbiased sample variance divides by M-1 (got {n_samples!r})"
        )
    check_latent_gaussian(mu, var)
    check_code_size(decoder, mu.shape[0])
    check_points(points)
    check_chunk(chunk)
    codes = sample_codes(mu, var, n_samples, generator)
    return code_statistics(decoder, codes, points, chunk, bf16, return_samples)


def code_statistics(
    decoder: Decoder,
    codes: Tensor,  # [M, D]
    points: Tensor,  # [P, 3]
    chunk: int = 512,
    bf16: bool = False,
    return_samples: bool = False,
) -> tuple[Tensor, Tensor] | tuple[Tensor, Tensor, Tensor]:
    """SDF mean [P] and unbiased variance [P] over the given codes (and the samples [M, P] if asked)."""
    n_samples = codes.shape[0]
    codes = codes.unsqueeze(1)  # [M, 1, D]
    dtype = output_dtype(points, bf16)
    n_points = points.shape[0]
    mean = torch.empty(n_points, dtype=dtype, device=points.device)
    variance = torch.empty_like(mean)
    samples = torch.empty(n_samples, n_points, dtype=dtype, device=points.device) if return_samples else None
    with frozen(decoder), torch.no_grad():
        for start in range(0, n_points, chunk):
            block = points[start : start + chunk]
            stop = start + block.shape[0]
            with decoder_autocast(points.device, bf16):
                sdf = decoder(block.unsqueeze(0), codes)  # [M, Pc]
            sdf = sdf.to(dtype)
            mean[start:stop] = sdf.mean(dim=0)
            variance[start:stop] = sdf.var(dim=0, correction=1)
            if samples is not None:
                samples[:, start:stop] = sdf
    if samples is not None:
        return mean, variance, samples
    return mean, variance
