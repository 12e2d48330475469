"""Fusion rules that do not treat the views' errors as independent, in latent space.

A view's code error is e_v = e_shape + e_view: e_shape ~ N(0, S) is common to every view of the
shape (what no image of it shows), e_view ~ N(0, c Sigma_v) is the view's own. Weighting the views
by Sigma_v^-1 as Bayesian fusion does, the fused error is e_shape + (weighted e_view), so

    mu = (sum_v Sigma_v^-1)^-1 sum_v Sigma_v^-1 mu_v          (Bayesian's mean, unchanged)
    Sigma = S + c (sum_v Sigma_v^-1)^-1                        (shared part never averages away)

S [D] (diagonal) and c are fitted on val (`ushape.recalibration.shared_error`). Covariance
intersection, with equal weights 1/V, keeps the same mean and gives V (sum_v Sigma_v^-1)^-1: a
fused variance that does not fall with V at all, whatever the views share; it needs no fit.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ushape.fusion.rules import (
    FusedCode,
    as_floating,
    check_views,
    fuse_bayesian,
    fuse_bayesian_k,
    product_of_gaussians,
)


def check_shared(shared_var: Tensor, view_scale: float, latent_size: int) -> None:
    """A ValueError that says what is wrong with a shared-error fit S [D], c for codes of `latent_size`."""
    if shared_var.ndim != 1 or shared_var.shape[0] != latent_size:
        raise ValueError(
            f"shared_var has shape {tuple(shared_var.shape)}, the codes have D = {latent_size}: "
            "refit it for this run with `python reconstruct.py --fit-temperature`"
        )
    if not torch.isfinite(shared_var).all() or (shared_var < 0).any():
        raise ValueError("shared_var must be finite and >= 0 everywhere (a variance per latent dimension)")
    if not (float(view_scale) > 0 and torch.isfinite(torch.tensor(float(view_scale)))):
        raise ValueError(f"view_scale must be a finite number > 0, got {view_scale!r}")


def add_shared(fused: FusedCode, shared_var: Tensor, view_scale: float) -> FusedCode:
    """A fused code of independent views (Bayesian) -> the same mean with variance S + c var."""
    shared = shared_var.to(fused.var)
    return FusedCode(fused.mu, shared + view_scale * fused.var, fused.kept)


def fuse_shared(
    mu: Tensor,  # [..., V, D]
    var: Tensor,  # [..., V, D]
    shared_var: Tensor,  # [D]
    view_scale: float = 1.0,
    var_floor: float = 1e-8,
) -> FusedCode:
    """Bayesian fusion's mean with the shared error added back: var = S + c (sum_v var_v^-1)^-1 -> [..., D]."""
    return _with_shared(lambda m, v: fuse_bayesian(m, v, var_floor), mu, var, shared_var, view_scale)


def fuse_shared_k(
    mu: Tensor,  # [..., V, D]
    var: Tensor,  # [..., V, D]
    shared_var: Tensor,  # [D]
    k: int,
    view_scale: float = 1.0,
    var_floor: float = 1e-8,
) -> FusedCode:
    """`fuse_shared` on the K views Bayesian-K keeps (lowest trace of the views' own var: the same choice)."""
    return _with_shared(lambda m, v: fuse_bayesian_k(m, v, k, var_floor), mu, var, shared_var, view_scale)


def _with_shared(fuse, mu: Tensor, var: Tensor, shared_var: Tensor, view_scale: float) -> FusedCode:
    """The views checked, fused by `fuse` (mu, var [..., V, D] -> FusedCode), and the shared error added back."""
    mu, var = as_floating(mu, var)
    check_views(mu, var)
    shared_var = torch.as_tensor(shared_var, dtype=var.dtype)
    check_shared(shared_var, view_scale, mu.shape[-1])
    return add_shared(fuse(mu, var), shared_var, view_scale)


def fuse_intersection(mu: Tensor, var: Tensor, var_floor: float = 1e-8) -> FusedCode:
    """Covariance intersection with equal weights: Bayesian's mean, var = V (sum_v var_v^-1)^-1 -> [..., D].

    The harmonic mean of the views' variances: the fused code is never claimed to be better known
    than a typical single view, the safe answer when the views' errors may be fully shared.
    """
    mu, var = as_floating(mu, var)
    check_views(mu, var)
    fused_mu, fused_var = product_of_gaussians(mu, var, var_floor)
    return FusedCode(
        fused_mu, fused_var * mu.shape[-2], torch.arange(mu.shape[-2], device=mu.device).expand(*mu.shape[:-1])
    )
