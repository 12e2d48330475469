"""Validation scores of predicted latent Gaussians against the stage-1 codes (latent space)."""

from __future__ import annotations

import torch
from torch import Tensor

from ushape.encoder.losses import energy_score, gaussian_nll
from ushape.metrics.calibration import calibration_curve, calibration_error


def latent_l2(mu: Tensor, target: Tensor) -> Tensor:
    """Mean Euclidean distance ||mu - z|| over the batch. mu, target [N, D] -> scalar."""
    return (mu - target).norm(dim=-1).mean()


def _average_ranks(x: Tensor) -> Tensor:
    """Ranks 0..N-1 of x [N], ties sharing their mean rank (as scipy.stats.rankdata does)."""
    values, inverse, counts = torch.unique(x, sorted=True, return_inverse=True, return_counts=True)
    first = torch.cumsum(counts, 0) - counts
    return (first + (counts - 1) / 2).double()[inverse]


def spearman_correlation(x: Tensor, y: Tensor) -> Tensor:
    """Spearman rank correlation of x [N] and y [N]; NaN when either is constant."""
    if x.shape != y.shape or x.ndim != 1 or x.numel() < 2:
        raise ValueError(f"x and y must be 1-D of equal length >= 2; got {tuple(x.shape)}, {tuple(y.shape)}")
    rx, ry = _average_ranks(x), _average_ranks(y)
    rx, ry = rx - rx.mean(), ry - ry.mean()
    return (rx * ry).sum() / (rx.norm() * ry.norm())


def variance_tracks_error(var: Tensor, mu: Tensor, target: Tensor) -> Tensor:
    """Spearman correlation, over the N predictions, of the covariance trace with the squared error.

    var, mu, target [N, D] -> scalar; > 0 when the model is less sure where it is more wrong, NaN for a
    constant variance.
    """
    return spearman_correlation(var.sum(-1), ((mu - target) ** 2).sum(-1))


def latent_scores(
    mu: Tensor,  # [N, D]
    logvar: Tensor,  # [N, D]
    target: Tensor,  # [N, D]
    n_samples: int = 1000,
    n_levels: int = 20,
    generator: torch.Generator | None = None,
) -> dict[str, Tensor]:
    """l2, es, nll, rank_corr (variance trace vs squared error) and calibration error of N(mu, exp(logvar)).

    For a deterministic model pass logvar = zeros: the paper's equal-variance baseline sigma^2 = 1
    (rank_corr is then NaN: a constant variance ranks nothing).
    """
    sigma = torch.exp(0.5 * logvar)
    p, freq = calibration_curve((mu - target).abs(), sigma, n_levels)
    return {
        "latent_l2": latent_l2(mu, target),
        "latent_es": energy_score(mu, logvar, target, n_samples=n_samples, generator=generator),
        "latent_nll": gaussian_nll(mu, logvar, target),
        "rank_corr": variance_tracks_error(logvar.exp(), mu, target),
        "calibration_error": torch.tensor(calibration_error(p, freq)),
    }
