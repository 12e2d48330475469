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
factor and a floor, T_sdf n^beta var + floor^2, fitted on the val shapes' SDF samples at n = 1, 3 and 10 views.
The factor may grow with the views refined on (beta > 0): measured on the tables model, the posterior's SDF
std shrinks faster with the views than its error does (docs/refinement_probes.md, "The refined SDF variance
fitted per number of views"); beta = 0 is on the grid, so a model that does not need it keeps one factor.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import torch
from torch import Tensor

from ushape.metrics.calibration import calibration_curve, calibration_error
from ushape.recalibration.temperature import CALIBRATION_GRID, fit_calibration_temperature_and_floor, floor_grid

# Scales tried: 2^(-k/4), k = 0..48 (1 down to 2^-12).
SCALE_GRID = tuple(2.0 ** (-k / 4) for k in range(49))
# Exponents tried for the refined SDF factor's growth with the views refined on, T n^beta: 0 (one factor at
# every count) to 0.5 (the factor ~3x larger at 10 views than at one).
VIEW_EXPONENT_GRID = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)


class SdfFit(NamedTuple):
    """The refined SDF variance's fit, T n^beta var + floor^2, and each group's calibration error before (T = 1,
    beta = 0, no floor) and after."""

    temperature: float
    floor: float
    view_exponent: float
    before: list[float]
    after: list[float]


def temperature_at_views(temperature: float, view_exponent: float, n_views: int) -> float:
    """T n^beta: the factor on the SDF variance of a posterior refined on n_views views."""
    if not (isinstance(n_views, int) and n_views >= 1):
        raise ValueError(
            f"a refined posterior's SDF factor needs the number of views refined on (>= 1), got {n_views!r}"
        )
    return float(temperature) * n_views ** float(view_exponent)


def refined_sdf_temperature(fit: dict, n_views: int) -> float:
    """The factor a stored fit (a mode's record in refinement_calibration.json, or its "seen" model) gives a
    posterior refined on n_views views; a fit stored without "sdf_view_exponent" has the same at every count."""
    return temperature_at_views(fit["sdf_temperature"], fit.get("sdf_view_exponent", 0.0), n_views)


def _view_counts(n_groups: int, view_counts: Sequence[int] | None, exponents: Sequence[float]) -> list[int]:
    """One count per group; without counts only beta = 0 can be fitted."""
    if not exponents:
        raise ValueError("no view exponents to try: pass at least one (0.0: the same factor at every count)")
    if view_counts is None:
        if any(beta != 0 for beta in exponents):
            raise ValueError("a factor that grows with the views needs view_counts: one count per group")
        return [1] * n_groups
    if len(view_counts) != n_groups or any(int(n) < 1 for n in view_counts):
        raise ValueError(f"pass one view count (>= 1) per group: {n_groups} groups, counts {list(view_counts)}")
    return [int(n) for n in view_counts]


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
    view_counts: Sequence[int] | None = None,  # the groups' numbers of views (needed for beta > 0)
    exponents: Sequence[float] = (0.0,),
) -> SdfFit:
    """The refined posterior's SDF variance, T n^beta var + floor^2, fitted on val shapes refined on 1, 3 and 10
    views: T, the floor and beta (over `exponents`) minimise the worst group's calibration error (ties: the
    smaller beta, then the smaller floor).

    The refined code's SDF error has a part no direction of its posterior carries (the decoder cannot draw
    the shape exactly; where the views pin the visible surface, less of it is left than at the shape's own
    code), so a floor is fitted beside the factor, between 0 and the decoder's own misfit (`misfit`: the RMS
    clamped SDF error of the val shapes' own codes, `temperature.json`'s `sdf_decoder_misfit`).
    """
    if not groups:
        raise ValueError("no refined val shapes to fit the SDF variance on: pass at least one (|error|, std) group")
    counts = _view_counts(len(groups), view_counts, exponents)
    floors = floor_grid(misfit) if misfit > 0 else (0.0,)  # a decoder that draws its val shapes exactly: no floor
    best = None
    for beta in exponents:
        scaled = [(e, s * n ** (beta / 2)) for (e, s), n in zip(groups, counts)]  # the std: sqrt of n^beta
        t, floor, _, after = fit_calibration_temperature_and_floor(scaled, floors, n_levels)
        if best is None or max(after) < max(best[3]):
            best = (t, floor, float(beta), after)
    before = [
        calibration_error(*calibration_curve(e.double().reshape(-1), s.double().reshape(-1), n_levels))
        for e, s in groups
    ]
    return SdfFit(best[0], best[1], best[2], before, best[3])


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
    view_counts: Sequence[int] | None = None,  # the groups' numbers of views (needed for beta > 0)
    exponents: Sequence[float] = (0.0,),
) -> dict:
    """The refined SDF variance T n^beta var + floor^2 with one floor where a view saw the point and another
    where none did, both between 0 and the decoder's own misfit (floor_seen <= floor_unseen), T, beta (over
    `exponents`) and the floors fitted on val so that the worst calibration error over the groups' seen and
    unseen points, each scored on its own, is least (ties: the smaller beta, smaller floors, then the T closest
    to 1).

    Why: the refined code's SDF error is measured larger where no view looked (the MAP's median |error| on
    unseen ground-truth samples 1.3-2.3x that on seen ones with masks, 2-4x with depth, cpu_2h chairs), while
    the variance propagated from the code's posterior is alike on both (no code direction moves one side of
    the shape only). The misfit the views pinned is the seen floor's; the unseen floor keeps what the decoder
    cannot draw. -> {"sdf_temperature", "sdf_view_exponent", "floor_seen", "floor_unseen", "before" (per group,
    T = 1, no floor), "after" (per group), "after_seen", "after_unseen" (per group, None where a group has no
    such point)}.
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
    counts = _view_counts(len(checked), view_counts, exponents)
    floors = floor_grid(misfit) if misfit > 0 else (0.0,)
    best = None
    for beta in exponents:
        fit = _fit_seen([(e, v * n**beta, seen) for (e, v, seen), n in zip(checked, counts)], floors, n_levels, grid)
        worst = max(x for x in fit["after_seen"] + fit["after_unseen"] if x is not None)
        if best is None or worst < best[0]:
            best = (worst, {**fit, "sdf_view_exponent": float(beta)})
    return {**best[1], "before": [_ce(e, v, n_levels) for e, v, _ in checked]}


def _ce(abs_error: Tensor, var: Tensor, n_levels: int) -> float:
    return calibration_error(*calibration_curve(abs_error, var.sqrt(), n_levels))


def _fit_seen(
    checked: Sequence[tuple[Tensor, Tensor, Tensor]],  # per group: (|error| [P], variance [P], seen [P] bool)
    floors: Sequence[float],
    n_levels: int,
    grid: tuple[float, ...],
) -> dict:
    """`fit_sdf_recalibration_seen` at one beta (the variances already scaled by n^beta)."""

    def parts(t: float, floor: float, seen_part: bool) -> list[float | None]:
        """Per group, the CE of its seen (or unseen) points with that class's floor (None: no such point)."""
        return [
            _ce(e[k], t * v[k] + floor**2, n_levels) if k.any() else None
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
        "after": [_ce(e, seen_floor_variance(v, s, t, fs, fu), n_levels) for e, v, s in checked],
        "after_seen": parts(t, fs, True),
        "after_unseen": parts(t, fu, False),
    }
