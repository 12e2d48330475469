"""Fusion rules for V views' diagonal Gaussians over the latent code (all in latent space).

Every rule takes `mu` and `var` of shape [V, D], or [B, V, D] for a batch of objects, and
returns a `FusedCode` with `mu`, `var` of shape [D] (or [B, D]) and `kept`, the indices of
the views that went into the result ([K] or [B, K], ascending view order).
"""

from __future__ import annotations

import operator
import warnings
from typing import NamedTuple

import torch
from torch import Tensor


class FusedCode(NamedTuple):
    """A fused latent Gaussian and the views it was built from."""

    mu: Tensor  # [..., D]
    var: Tensor  # [..., D] diagonal covariance (these rules); a posterior refined on the views holds [D, D]
    kept: Tensor  # [..., K] long, view indices in ascending order


def as_floating(mu: Tensor, var: Tensor) -> tuple[Tensor, Tensor]:
    """mu, var with integer or bool inputs promoted to torch's default float dtype (floats kept as they are)."""
    return tuple(t if t.is_floating_point() else t.to(torch.get_default_dtype()) for t in (mu, var))


def check_views(mu: Tensor, var: Tensor) -> None:
    """Raise a ValueError that says what is wrong with per-view Gaussians mu, var [..., V, D]."""
    if mu.shape != var.shape:
        raise ValueError(
            f"mu {tuple(mu.shape)} and var {tuple(var.shape)} must have the same shape [V, D] or [B, V, D] "
            "(one diagonal variance per latent dimension)"
        )
    if mu.ndim not in (2, 3):
        raise ValueError(f"expected per-view codes of shape [V, D] or [B, V, D], got {tuple(mu.shape)}")
    if mu.shape[-2] == 0:
        raise ValueError("no views to fuse: pass at least one view's (mu, var)")
    if mu.shape[-1] == 0:
        raise ValueError("latent size D is 0: codes need at least one dimension")
    for name, t in (("mu", mu), ("var", var)):
        bad = ~torch.isfinite(t)
        if bad.any():
            views = sorted({int(v) for v in bad.nonzero()[:, -2].tolist()})
            raise ValueError(f"{name} holds NaN/inf values in view(s) {views}; drop or repair those views")
    negative = var < 0
    if negative.any():
        views = sorted({int(v) for v in negative.nonzero()[:, -2].tolist()})
        raise ValueError(f"var is negative in view(s) {views}; variances must be >= 0 (did you pass log-variance?)")


def check_k(k: int) -> int:
    """k as a Python int, or a ValueError unless it is an integer >= 1 (views to keep)."""
    try:
        value = operator.index(k) if not isinstance(k, bool) else None
    except TypeError:
        value = None
    if value is None or value < 1:
        raise ValueError(f"k must be an integer >= 1 (the number of views to keep), got {k!r}")
    return value


def _all_views(mu: Tensor) -> Tensor:
    """Indices 0..V-1 shaped like a `kept` field for mu [..., V, D]."""
    kept = torch.arange(mu.shape[-2], device=mu.device)
    return kept.expand(*mu.shape[:-2], mu.shape[-2])


def fuse_average(mu: Tensor, var: Tensor) -> FusedCode:
    """FroDO*'s equal-weight mean of the views' codes, in latent space.

    mu, var [..., V, D] -> FusedCode(mu [..., D], var [..., D], kept [..., V]).
    The returned variance is that of the average of V independent estimates,
    Var(mean_i z_i) = sum_i var_i / V^2 = mean(var) / V: the honest spread of this
    estimator if the views' errors are independent, so it shrinks with V like Bayesian
    fusion does, but without favouring the confident views.
    """
    mu, var = as_floating(mu, var)
    check_views(mu, var)
    n_views = mu.shape[-2]
    return FusedCode(mu.mean(dim=-2), var.mean(dim=-2) / n_views, _all_views(mu))


def product_of_gaussians(mu: Tensor, var: Tensor, var_floor: float) -> tuple[Tensor, Tensor]:
    """Information-form product of diagonal Gaussians mu, var [..., V, D] -> (mu, var) [..., D]."""
    if mu.shape[-2] == 1:
        # A single view is its own posterior; skip 1/(1/v), which is not exact in floating point.
        return mu[..., 0, :].clone(), var[..., 0, :].clamp(min=var_floor)
    information = var.clamp(min=var_floor).reciprocal()
    total = information.sum(dim=-2)
    # mu as a convex combination (weights summing to 1): information * mu overflows float32 for
    # |mu| ~ 1e30 at the variance floor, although the fused mean itself is representable.
    fused_mu = (information / total.unsqueeze(-2) * mu).sum(dim=-2)
    return fused_mu, total.reciprocal()


def fuse_bayesian(mu: Tensor, var: Tensor, var_floor: float = 1e-8) -> FusedCode:
    """Product of the views' Gaussians (paper Eq. gaussian_fusion), in latent space.

    mu, var [..., V, D] -> FusedCode(mu [..., D], var [..., D], kept [..., V]).
    Sigma = (sum_i Sigma_i^-1)^-1, mu = Sigma sum_i Sigma_i^-1 mu_i. Variances below
    `var_floor` are raised to it, so one over-confident view cannot divide by zero.
    """
    if var_floor <= 0:
        raise ValueError(f"var_floor must be > 0, got {var_floor}")
    mu, var = as_floating(mu, var)
    check_views(mu, var)
    fused_mu, fused_var = product_of_gaussians(mu, var, var_floor)
    return FusedCode(fused_mu, fused_var, _all_views(mu))


def select_lowest_trace(var: Tensor, k: int) -> Tensor:
    """Indices [..., K] (ascending) of the K views with the smallest covariance trace; var [..., V, D].

    Ties go to the earlier view, so the choice is deterministic.
    """
    trace = var.sum(dim=-1)
    order = torch.sort(trace, dim=-1, stable=True).indices
    return torch.sort(order[..., :k], dim=-1).values


def fuse_bayesian_k(mu: Tensor, var: Tensor, k: int, var_floor: float = 1e-8) -> FusedCode:
    """Bayesian-K: product of the K views with the lowest covariance trace, in latent space.

    mu, var [..., V, D] -> FusedCode(mu [..., D], var [..., D], kept [..., K]).
    The paper's outlier rejection ("Bayesian-N"): a very uncertain view (e.g. occluded) is
    dropped instead of being fused with a small weight. K > V uses all views and warns.
    """
    k = check_k(k)
    if var_floor <= 0:
        raise ValueError(f"var_floor must be > 0, got {var_floor}")
    mu, var = as_floating(mu, var)
    check_views(mu, var)
    n_views = mu.shape[-2]
    if k > n_views:
        warnings.warn(f"Bayesian-K with k={k} but only {n_views} views: fusing all of them", stacklevel=2)
        k = n_views
    kept = select_lowest_trace(var, k)
    index = kept.unsqueeze(-1).expand(*kept.shape, mu.shape[-1])
    fused_mu, fused_var = product_of_gaussians(torch.gather(mu, -2, index), torch.gather(var, -2, index), var_floor)
    return FusedCode(fused_mu, fused_var, kept)
