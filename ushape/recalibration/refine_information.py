"""How much of the views' information the refined posterior may claim, fitted on val.

The refinement's Laplace posterior is (Sigma^-1 + J^T W J)^-1 with one row per ray. Neighbouring rays'
residuals are not independent (one silhouette edge is seen by many rays), and the decoder cannot draw
the true shape exactly, so J^T W J over-counts what the views tell: measured, the true code is several
prior standard deviations from the MAP in directions the posterior calls certain. The fix is the usual
one for correlated residuals (an effective number of observations): the posterior covariance
(Sigma^-1 + s J^T W J)^-1 with a scale s in (0, 1], chosen on val shapes so that the calibration error
of |z* - z_true| against the posterior's marginal std is smallest. The MAP is not refitted (s only
scales the curvature at it); `RefineSettings.information_scale` carries s.

The SDF variance propagated from that posterior is recalibrated on its own (`fit_sdf_recalibration`): a
factor and a floor, T_sdf var + floor^2, fitted on the val shapes' SDF samples at 1, 3 and 10 views.
"""

from __future__ import annotations

import math
from typing import Sequence

import torch
from torch import Tensor

from ushape.metrics.calibration import calibration_curve, calibration_error
from ushape.recalibration.temperature import CALIBRATION_GRID, fit_calibration_temperature_and_floor, floor_grid

# Scales tried: 2^(-k/4), k = 0..48 (1 down to 2^-12).
SCALE_GRID = tuple(2.0 ** (-k / 4) for k in range(49))


def scaled_posterior_std(
    prior_precision: Tensor,  # [D, D]
    information: Tensor,  # [D, D] J^T W J at the MAP
    scale: float,
) -> Tensor:
    """Marginal std [D] of (prior_precision + scale information)^-1."""
    cov = torch.linalg.inv(prior_precision.double() + scale * information.double())
    return torch.diagonal(cov).clamp_min(0).sqrt()


def fit_information_scale(
    errors: Sequence[Tensor],  # each [D]: MAP minus the shape's own code
    prior_precisions: Sequence[Tensor],  # each [D, D]
    informations: Sequence[Tensor],  # each [D, D]
    n_levels: int = 20,
    grid: tuple[float, ...] = SCALE_GRID,
) -> tuple[float, float, float]:
    """(s, latent calibration error at s = 1, at s): the s in grid with the least calibration error (ties: larger s)."""
    if not errors or not (len(errors) == len(prior_precisions) == len(informations)):
        raise ValueError("pass one error, prior precision and information per refined shape (at least one)")
    abs_error = torch.cat([e.double().abs().reshape(-1) for e in errors])

    def score(scale: float) -> float:
        std = torch.cat([scaled_posterior_std(p, a, scale) for p, a in zip(prior_precisions, informations)])
        return calibration_error(*calibration_curve(abs_error, std, n_levels))

    scores = [(score(s), -math.log(s), s) for s in grid]
    best_error, _, best = min(scores)
    return best, score(1.0), best_error


def fit_sdf_recalibration(
    groups: Sequence[tuple[Tensor, Tensor]],  # per number of views refined on: (|SDF error| [P], SDF std [P])
    misfit: float,
    n_levels: int = 20,
) -> tuple[float, float, list[float], list[float]]:
    """(T_sdf, floor, calibration error per group as given, at (T_sdf, floor)) of the refined posterior's SDF
    variance, T_sdf var + floor^2, fitted on val shapes refined on 1, 3 and 10 views (the worst group's error
    is minimised).

    The refined code's SDF error has a part no direction of its posterior carries (the decoder cannot draw
    the shape exactly; where the views pin the visible surface, less of it is left than at the shape's own
    code), so a floor is fitted beside the factor, between 0 and the decoder's own misfit (`misfit`: the RMS
    clamped SDF error of the val shapes' own codes, `temperature.json`'s `sdf_decoder_misfit`).
    """
    if not groups:
        raise ValueError("no refined val shapes to fit the SDF variance on: pass at least one (|error|, std) group")
    floors = floor_grid(misfit) if misfit > 0 else (0.0,)  # a decoder that draws its val shapes exactly: no floor
    return fit_calibration_temperature_and_floor(groups, floors, n_levels)


def seen_floor_variance(
    var: Tensor,  # [P] SDF variance propagated from the posterior
    seen: Tensor,  # [P] bool: some view saw the point
    temperature: float,
    floor_seen: float,
    floor_unseen: float,
) -> Tensor:  # [P]
    """T var + floor^2, the floor floor_seen where a view saw the point and floor_unseen where none did."""
    floor = torch.where(seen.bool(), floor_seen, floor_unseen).to(var.dtype)
    return temperature * var + floor.square()


def fit_sdf_recalibration_seen(
    groups: Sequence[tuple[Tensor, Tensor, Tensor]],  # per view count: (|SDF error| [P], SDF std [P], seen [P] bool)
    misfit: float,
    n_levels: int = 20,
    grid: tuple[float, ...] = CALIBRATION_GRID,
) -> dict:
    """The refined SDF variance T var + floor^2 with one floor where a view saw the point and another where
    none did, both between 0 and the decoder's own misfit (floor_seen <= floor_unseen), T and the floors
    fitted on val so that the worst calibration error over the groups' seen and unseen points, each scored on
    its own, is least (ties: smaller floors, then the T closest to 1).

    Why: the refined code's SDF error is measured larger where no view looked (the MAP's median |error| on
    unseen ground-truth samples 1.3-2.3x that on seen ones with masks, 2-4x with depth, cpu_2h chairs), while
    the variance propagated from the code's posterior is alike on both (no code direction moves one side of
    the shape only). The misfit the views pinned is the seen floor's; the unseen floor keeps what the decoder
    cannot draw. -> {"sdf_temperature", "floor_seen", "floor_unseen", "before" (per group, T = 1, no floor),
    "after" (per group), "after_seen", "after_unseen" (per group, None where a group has no such point)}.
    """
    if not groups:
        raise ValueError("no refined val shapes to fit the SDF variance on: pass at least one (|error|, std, seen)")
    checked = []
    for abs_error, std, seen in groups:
        abs_error, std, seen = abs_error.reshape(-1).double(), std.reshape(-1).double(), seen.reshape(-1).bool()
        if not (abs_error.shape == std.shape == seen.shape) or abs_error.numel() == 0:
            raise ValueError(
                f"|error| {tuple(abs_error.shape)}, std {tuple(std.shape)} and seen {tuple(seen.shape)} must be equal "
                "and non-empty"
            )
        checked.append((abs_error, std.square(), seen))
    floors = floor_grid(misfit) if misfit > 0 else (0.0,)

    def ce(abs_error: Tensor, var: Tensor) -> float:
        return calibration_error(*calibration_curve(abs_error, var.sqrt(), n_levels))

    def parts(t: float, floor: float, seen_part: bool) -> list[float | None]:
        """Per group, the CE of its seen (or unseen) points with that class's floor (None: no such point)."""
        return [
            ce(e[k], t * v[k] + floor**2) if k.any() else None
            for e, v, seen in checked
            for k in [seen if seen_part else ~seen]
        ]

    # The seen points' worst error depends on (T, floor_seen) only, the unseen ones' on (T, floor_unseen) only:
    # each is scored once per pair, not once per (T, floor_seen, floor_unseen).
    worst = {
        (part, t, f): max((x for x in parts(t, f, part) if x is not None), default=0.0)
        for part in (True, False)
        for t in grid
        for f in floors
    }
    best = min(
        ((t, fs, fu) for fs in floors for fu in floors if fs <= fu for t in grid),
        key=lambda c: (max(worst[True, c[0], c[1]], worst[False, c[0], c[2]]), c[2], c[1], abs(math.log(c[0]))),
    )
    t, fs, fu = best
    return {
        "sdf_temperature": t,
        "floor_seen": fs,
        "floor_unseen": fu,
        "before": [ce(e, v) for e, v, _ in checked],
        "after": [ce(e, seen_floor_variance(v, s, t, fs, fu)) for e, v, s in checked],
        "after_seen": parts(t, fs, True),
        "after_unseen": parts(t, fu, False),
    }
