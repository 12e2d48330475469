"""Temperature scaling of predicted variances (Guo et al. 2017), in latent space: var' = T * var.

T scales the variance, so the standard deviation scales by sqrt(T). With this choice the
Gaussian NLL is minimised in closed form, T = mean((z - mu)^2 / var) over every sample and
dimension: the mean squared standardised error, which is 1 for a calibrated model.
T > 1 widens over-confident predictions, T < 1 sharpens under-confident ones.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ushape.metrics.scores import gaussian_nll_1d


def _check(mu: Tensor, var: Tensor, target: Tensor) -> None:
    if not (mu.shape == var.shape == target.shape):
        raise ValueError(
            f"mu {tuple(mu.shape)}, var {tuple(var.shape)} and target {tuple(target.shape)} must share one shape [N, D]"
        )
    if mu.numel() == 0:
        raise ValueError("no validation samples: temperature scaling needs at least one (mu, var, target)")
    for name, t in (("mu", mu), ("var", var), ("target", target)):
        if not torch.isfinite(t).all():
            raise ValueError(f"{name} holds NaN/inf values; clean the validation set before fitting T")
    if (var <= 0).any():
        raise ValueError("var must be > 0 everywhere (a variance, not a log-variance); floor it before fitting T")


def fit_temperature(
    mu: Tensor,  # [N, D]
    var: Tensor,  # [N, D]
    target: Tensor,  # [N, D]
) -> float:
    """The T minimising the Gaussian NLL of target under N(mu, T var), in closed form."""
    _check(mu, var, target)
    standardised = (target.double() - mu.double()).square() / var.double()
    temperature = float(standardised.mean())
    if temperature == 0.0:
        raise ValueError("every prediction equals its target exactly: no spread to fit a temperature to")
    return temperature


def apply_temperature(var: Tensor, temperature: float) -> Tensor:
    """Recalibrated variance T * var (any shape), in the space var lives in."""
    try:
        value = float(temperature)
    except (TypeError, ValueError):
        raise ValueError(f"temperature must be a number, got {temperature!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"temperature must be a finite number > 0, got {temperature!r}")
    return var * value


def gaussian_nll_with_temperature(
    mu: Tensor,  # [N, D]
    var: Tensor,  # [N, D]
    target: Tensor,  # [N, D]
    temperature: float,
) -> float:
    """Mean Gaussian NLL per dimension (with the 0.5 log 2 pi constant) of target under N(mu, T var)."""
    _check(mu, var, target)
    scaled = apply_temperature(var.double(), temperature)
    return float(gaussian_nll_1d(mu.double(), scaled, target.double()).mean())
