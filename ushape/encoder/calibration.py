"""Calibration of predicted Gaussians (supplement, "Drawing a Calibration Plot"), any space.

Each scalar prediction (one latent dimension of one image, or one SDF value) is an independent
univariate N(mu_i, sigma_i^2). For T probabilities p_t in (0, 1), F_t is the fraction of errors
|x_i - mu_i| within Q(p_t) sigma_i, with Q the two-sided normal quantile (Q(0.9973) = 3).
A calibrated predictor has F_t = p_t.
"""

from __future__ import annotations

import torch
from torch import Tensor


def probability_levels(n_levels: int) -> Tensor:
    """T probabilities evenly inside (0, 1): t / (T + 1), t = 1..T. -> [T]."""
    if n_levels < 1:
        raise ValueError(f"n_levels must be >= 1, got {n_levels}")
    return torch.arange(1, n_levels + 1, dtype=torch.float64) / (n_levels + 1)


def two_sided_quantile(p: Tensor) -> Tensor:
    """Q(p) with P(|X| <= Q(p)) = p for X ~ N(0, 1): Phi^-1((1 + p) / 2). p [T] -> [T]."""
    return torch.special.ndtri((1 + p.double()) / 2)


def calibration_curve(abs_error: Tensor, sigma: Tensor, n_levels: int = 20) -> tuple[Tensor, Tensor]:
    """(p [T], F [T]): fraction of abs_error [N] within Q(p_t) * sigma [N], per level p_t."""
    abs_error, sigma = abs_error.reshape(-1).double(), sigma.reshape(-1).double()
    if abs_error.shape != sigma.shape or abs_error.numel() == 0:
        raise ValueError(f"abs_error and sigma must be non-empty and the same size; got {abs_error.numel()}, {sigma.numel()}")
    p = probability_levels(n_levels).to(abs_error.device)
    inside = abs_error[None, :] <= two_sided_quantile(p)[:, None] * sigma[None, :]
    return p, inside.double().mean(dim=1)


def calibration_error(p: Tensor, freq: Tensor) -> Tensor:
    """Mean |F_t - p_t| over the levels: 0 for perfect calibration, at most ~0.5. -> scalar."""
    return (freq.double() - p.double()).abs().mean()

