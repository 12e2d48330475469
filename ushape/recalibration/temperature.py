"""Temperature scaling of predicted variances (Guo et al. 2017), in latent space: var' = T * var.

T scales the variance, so the standard deviation scales by sqrt(T). With this choice the
Gaussian NLL is minimised in closed form, T = mean((z - mu)^2 / var) over every sample and
dimension: the mean squared standardised error, which is 1 for a calibrated model.
T > 1 widens over-confident predictions, T < 1 sharpens under-confident ones.
`fit_calibration_temperature` fits the same kind of factor where the NLL is not the score (the
propagated SDF variance), by the calibration error over a grid; `fit_calibration_temperature_across`
fits one such factor to several groups at once (the worst group's calibration error is minimised).
"""

from __future__ import annotations

import math
from typing import Sequence

import torch
from torch import Tensor

from ushape.metrics.calibration import calibration_curve, calibration_error
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


# Variance factors tried by `fit_calibration_temperature`: 1/16 to 16, 2^(1/8) apart (std 1/4 to 4).
CALIBRATION_GRID = tuple(2.0 ** (k / 8) for k in range(-32, 33))


def fit_calibration_temperature(
    abs_error: Tensor,  # [P]
    std: Tensor,  # [P]
    n_levels: int = 20,
    grid: tuple[float, ...] = CALIBRATION_GRID,
) -> tuple[float, float, float]:
    """The variance factor T (std' = sqrt(T) std) minimising the calibration error of |error| against std.

    For a space where T is not fitted by the NLL: the SDF std propagated from a latent Gaussian that
    was calibrated in latent space is measured still too small (1.04-1.24x, docs/stage2_encoder.md), and
    its NLL, on values clamped at the decoder's training clamp, is not what is reported; the
    calibration error is. -> (T, calibration error at T = 1, at T), over the grid of factors.
    """
    abs_error, std = abs_error.reshape(-1).double(), std.reshape(-1).double()
    if abs_error.shape != std.shape or abs_error.numel() == 0:
        raise ValueError(f"abs_error {tuple(abs_error.shape)} and std {tuple(std.shape)} must be equal and non-empty")
    if not (torch.isfinite(abs_error).all() and torch.isfinite(std).all()) or (std < 0).any():
        raise ValueError("abs_error and std must be finite, with std >= 0 (a standard deviation, not a log)")
    scores = [(calibration_error(*calibration_curve(abs_error, std * math.sqrt(t), n_levels)), t) for t in grid]
    best_error, best = min(scores, key=lambda pair: (pair[0], abs(math.log(pair[1]))))
    before = calibration_error(*calibration_curve(abs_error, std, n_levels))
    return best, before, best_error


def fit_calibration_temperature_across(
    groups: Sequence[tuple[Tensor, Tensor]],  # per group: (|error| [P_g], std [P_g])
    n_levels: int = 20,
    grid: tuple[float, ...] = CALIBRATION_GRID,
    floor: float = 0.0,
) -> tuple[float, list[float], list[float]]:
    """The one variance factor T (std' = sqrt(T std^2 + floor^2)) whose worst calibration error over the groups is
    least. floor: a std every prediction carries whatever the code's, e.g. the decoder's own misfit
    (`decoder_misfit`); 0: std' = sqrt(T) std.

    For a variance that must be calibrated at several settings at once (the fused SDF variance at 1, 3
    and 10 fused views): each group is scored on its own, and T minimises the largest of their calibration
    errors (ties: the T closest to 1). -> (T, each group's calibration error as given (T = 1, no floor), at T
    with the floor).
    """
    if not groups:
        raise ValueError("no groups to fit a temperature on: pass at least one (|error|, std) pair")
    if not (math.isfinite(floor) and floor >= 0):
        raise ValueError(f"floor must be a finite std >= 0, got {floor!r}")
    checked = []
    for abs_error, std in groups:
        abs_error, std = abs_error.reshape(-1).double(), std.reshape(-1).double()
        if abs_error.shape != std.shape or abs_error.numel() == 0:
            raise ValueError(
                f"abs_error {tuple(abs_error.shape)} and std {tuple(std.shape)} must be equal and non-empty"
            )
        if not (torch.isfinite(abs_error).all() and torch.isfinite(std).all()) or (std < 0).any():
            raise ValueError("abs_error and std must be finite, with std >= 0 (a standard deviation, not a log)")
        checked.append((abs_error, std))

    def errors(factor: float, floor: float = floor) -> list[float]:
        return [
            calibration_error(*calibration_curve(e, (factor * s.square() + floor**2).sqrt(), n_levels))
            for e, s in checked
        ]

    best = min(grid, key=lambda t: (max(errors(t)), abs(math.log(t))))
    return best, errors(1.0, 0.0), errors(best)


def floor_grid(scale: float) -> tuple[float, ...]:
    """Floors tried by `fit_calibration_temperature_and_floor`: 0 and `scale` times 2^(k/2), k = -8..0 (scale/16
    to scale). `scale` is the decoder's own misfit (the RMS SDF error of the shapes' own codes): the error no
    code direction carries is at most that large. A floor fitted freely takes over the variance instead
    (measured: 70-80 % of it, the factor shrinking to 0.3), a std that no longer says where the error is."""
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"the floor's scale must be a finite std > 0, got {scale!r}")
    return (0.0, *(scale * 2.0 ** (k / 2) for k in range(-8, 1)))


def fit_calibration_temperature_and_floor(
    groups: Sequence[tuple[Tensor, Tensor]],  # per group: (|error| [P_g], std [P_g])
    floors: Sequence[float],
    n_levels: int = 20,
    grid: tuple[float, ...] = CALIBRATION_GRID,
) -> tuple[float, float, list[float], list[float]]:
    """The factor T and floor (std' = sqrt(T std^2 + floor^2)) whose worst calibration error over the groups is
    least, T over `grid` and the floor over `floors` (ties: the smaller floor, then the T closest to 1).

    For a variance whose error has a part no latent direction carries: the decoder's own misfit, which a
    refined code may have pinned down in part, so the floor is fitted rather than measured. -> (T, floor,
    each group's calibration error as given (T = 1, no floor), at (T, floor)).
    """
    if not floors:
        raise ValueError("no floors to try: pass at least one (0 for none)")
    fits = [(fit_calibration_temperature_across(groups, n_levels, grid, floor), floor) for floor in floors]
    (temperature, before, after), floor = min(fits, key=lambda fit: (max(fit[0][2]), fit[1]))
    return temperature, floor, before, after
