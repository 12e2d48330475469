"""Univariate proper scores for Gaussian predictions (the paper's Table S1, e.g. in SDF space).

Both take the predicted mean and *variance* and an observation, elementwise over any
broadcastable shape, and return the per-element score (lower is better); average as needed.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

_LOG_2PI = math.log(2 * math.pi)


def _check_var(var: Tensor) -> None:
    if (var <= 0).any():
        raise ValueError("var must be > 0 everywhere (a variance, not a standard deviation or log-variance)")


def gaussian_nll_1d(mu: Tensor, var: Tensor, x: Tensor) -> Tensor:
    """Negative log density of x under N(mu, var), elementwise, *including* the 0.5 log(2 pi) constant.

    With the constant the score is a true log-likelihood, so it can be negative (as in Table S1)
    and is comparable with any other density's NLL.
    """
    _check_var(var)
    return 0.5 * (_LOG_2PI + torch.log(var) + (x - mu).square() / var)


def energy_score_1d(mu: Tensor, var: Tensor, x: Tensor) -> Tensor:
    """Energy score of N(mu, var) at x, elementwise, in closed form (in 1-D it equals the CRPS).

    ES = E|X - x| - 0.5 E|X - X'| = sigma [z (2 Phi(z) - 1) + 2 phi(z) - 1/sqrt(pi)], z = (x - mu)/sigma.
    """
    _check_var(var)
    sigma = var.sqrt()
    z = (x - mu) / sigma
    cdf = torch.special.ndtr(z)
    pdf = torch.exp(-0.5 * z.square()) / math.sqrt(2 * math.pi)
    return sigma * (z * (2 * cdf - 1) + 2 * pdf - 1 / math.sqrt(math.pi))
