"""One Gaussian over the latent code, diagonal or full: checks, a square-root factor, marginals and the trace.

An encoder predicts a diagonal Gaussian, var [D] (one variance per dimension), and the paper's fusion
rules keep it diagonal. A posterior refined against the views couples the dimensions: its covariance
is a full [D, D] matrix. Every consumer of a latent Gaussian (propagation, depth std, sampling, the
next-best-view loop) takes either form; these helpers are what they share, so a [D] var keeps
exactly the arithmetic it always had and a [D, D] one is handled in one place.
"""

from __future__ import annotations

import torch
from torch import Tensor


def is_full_covariance(var: Tensor) -> bool:
    """True for a [D, D] covariance, False for a diagonal var [D] (one Gaussian, not a batch)."""
    return var.ndim == 2


def check_covariance(cov: Tensor) -> None:
    """Raise a ValueError unless cov is a finite, symmetric, positive semi-definite [D, D] matrix.

    Symmetry and the smallest eigenvalue are judged to sqrt(eps) of cov's dtype relative to its largest
    entry (3e-4 in float32), so a covariance computed as an inverse in float32 passes and a matrix that
    is not a covariance does not. Costs one Cholesky factorisation; eigenvalues only when it fails.
    """
    if cov.ndim != 2 or cov.shape[0] != cov.shape[1]:
        raise ValueError(f"a full covariance must be a square matrix [D, D], got {tuple(cov.shape)}")
    if not torch.isfinite(cov).all():
        raise ValueError("the covariance holds NaN/inf; the latent Gaussian must be finite")
    tol = float(torch.finfo(cov.dtype).eps) ** 0.5 if cov.is_floating_point() else 0.0
    scale = float(cov.abs().max()) if cov.numel() else 0.0
    asymmetry = float((cov - cov.T).abs().max()) if cov.numel() else 0.0
    if asymmetry > tol * scale:
        raise ValueError(
            f"the covariance [D, D] is not symmetric (max |S - S^T| = {asymmetry:.3g}, largest entry {scale:.3g}); "
            "symmetrise it with (S + S^T) / 2 if the difference is rounding"
        )
    wide = cov.double()
    if int(torch.linalg.cholesky_ex(wide).info) == 0:
        return  # positive definite
    smallest = float(torch.linalg.eigvalsh(wide).min())
    if smallest < -tol * scale:
        raise ValueError(
            f"the covariance [D, D] is not positive semi-definite (smallest eigenvalue {smallest:.3g}, "
            f"largest entry {scale:.3g}): pass a covariance, not a precision difference or a log-variance"
        )


def covariance_factor(cov: Tensor) -> Tensor:  # [D, D] -> [D, D]
    """A square root L of the covariance, L L^T = cov, in cov's dtype (computed in float64).

    Cholesky where cov is positive definite; a singular PSD cov falls back to its eigendecomposition,
    V sqrt(max(lambda, 0)), which needs no jitter; both after symmetrising, (S + S^T) / 2. A diagonal
    cov gives diag(sqrt(var)) in its own dtype, so codes sampled from it are bit for bit those of the
    [D] form (float32 sqrt on CPU is not always the correctly rounded float64 one).
    """
    diagonal = cov.diagonal().contiguous()
    if torch.equal(cov, torch.diag_embed(diagonal)):  # in cov's dtype, as the [D] form takes var.sqrt()
        return torch.diag_embed(diagonal.clamp_min(0).sqrt())
    wide = cov.double()
    wide = (wide + wide.T) / 2
    factor, info = torch.linalg.cholesky_ex(wide)
    if int(info) != 0:
        eigenvalues, eigenvectors = torch.linalg.eigh(wide)
        factor = eigenvectors * eigenvalues.clamp_min(0).sqrt()
    return factor.to(cov.dtype)


def marginal_variance(var: Tensor) -> Tensor:  # [D] | [D, D] -> [D]
    """Each dimension's own variance: var itself, or the covariance's diagonal."""
    return var.diagonal() if is_full_covariance(var) else var


def latent_trace(var: Tensor) -> Tensor:  # [D] | [D, D] -> []
    """The covariance's trace, sum of the marginal variances (of a [D, D] covariance: its diagonal sum)."""
    return marginal_variance(var).sum()
