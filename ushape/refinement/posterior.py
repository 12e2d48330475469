"""The code refined on what the views show: a MAP by Levenberg-Marquardt and its full-covariance Laplace posterior.

Energy, with the fused Gaussian N(mu, Sigma) as the prior and every view's residuals r(z) (masks,
and depths with use_depth) with per-row weights W = 1 / sigma^2:

    E(z) = 1/2 (z - mu)^T Sigma^-1 (z - mu) + 1/2 sum_i W_i r_i(z)^2.

Each step solves (H + lambda diag H) dz = -g with the Gauss-Newton H = Sigma^-1 + J^T W J and
g = Sigma^-1 (z - mu) + J^T W r; a step that does not lower E is retried with a larger lambda.
Depth and free-space rows are Huber-weighted (weight min(1, delta / |r|)): a return that a code puts
on another part than the view saw must not drag the code.

Two optional guards against the local minima a sharp silhouette has: the LM can run at a sequence of
silhouette sharpnesses (`tau_schedule`, multiples of the observation's tau, widest first: a wide
sigmoid gives rows to pixels the shape misses by far), and it can start from the lowest-energy of the
prior's mean and `starts` draws from the prior (the same energy, so the MAP it looks for is the same).

At the optimum z* the Laplace posterior is N(z*, (Sigma^-1 + s J^T W J)^-1), a full [D, D] covariance
(s = `information_scale`, 1 unless fitted on val: ushape.recalibration.refine_information): directions
of z that no residual moves keep the prior's variance exactly, those a view constrains shrink.

No views with a camera, no observed foreground, a non-finite residual, or a code driven past
`max_mahalanobis` prior standard deviations: the prior is returned unchanged, with `fallback` naming
why and a warning logged (callers count them from the records).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import torch
from torch import Tensor

from ushape.decoder.query import frozen
from ushape.refinement.defaults import REFINE_DEFAULTS, with_defaults
from ushape.refinement.observation import KINDS, ObservationSettings, Residuals, residuals, with_jacobian
from ushape.refinement.views import ObservedView, ScreenedView, screen_view

log = logging.getLogger(__name__)
MODES = ("masks", "depth")
MIN_SIZE = 4  # rays per image side: fewer cannot draw an outline


@dataclass(frozen=True)
class RefineSettings:
    """What the refinement compares and how hard it trusts it (defaults: conf/refine.yaml)."""

    mode: str = "masks"  # "masks": silhouettes only; "depth": silhouettes and depth returns
    sigma_mask: float = REFINE_DEFAULTS["sigma_mask"]  # occupancy residual's std per ray
    sigma_depth: float = REFINE_DEFAULTS["sigma_depth"]  # depth residual's std per ray (unit-sphere frame)
    huber_depth: float = 0.05  # depth residuals past this are down-weighted
    iterations: int = REFINE_DEFAULTS["iterations"]
    damping: float = 1e-3  # initial lambda
    tolerance: float = 1e-3  # stop when E falls by less than this fraction (1e-4 cost 2-4x the steps, same IoU)
    max_mahalanobis: float = 60.0  # ||z* - mu|| in prior stds past this counts as diverged
    # Silhouette sharpness per LM stage, x observation.tau, e.g. (4, 2, 1). One stage by default: on the
    # trained chairs the LM already ends below the true code's energy (docs/refinement.md), and each stage costs a run.
    tau_schedule: tuple[float, ...] = (1.0,)
    # prior draws scored beside the prior's mean; the LM starts from the lowest energy
    starts: int = REFINE_DEFAULTS["starts"]
    seed: int = 0  # of those draws
    # s in the Laplace covariance (Sigma^-1 + s J^T W J)^-1, fitted on val (recalibration)
    information_scale: float = REFINE_DEFAULTS["information_scale"]
    observation: ObservationSettings = field(default_factory=ObservationSettings)


def refine_settings(
    mode: str = "masks",
    size: int | None = None,
    sigma_mask: float | None = None,
    sigma_depth: float | None = None,
    iterations: int | None = None,
    information_scale: float | None = None,
    starts: int | None = None,
) -> RefineSettings:
    """RefineSettings from the flat knobs a config or a command line gives (size: rays per image side; starts:
    prior draws scored beside the prior's mean, the LM starting from the lowest energy); a knob not given
    (None) is conf/refine.yaml's."""
    knobs = with_defaults(
        size=size,
        sigma_mask=sigma_mask,
        sigma_depth=sigma_depth,
        iterations=iterations,
        information_scale=information_scale,
        starts=starts,
    )
    size, starts = knobs.pop("size"), knobs.pop("starts")
    if int(starts) != starts or starts < 0:
        raise ValueError(f"starts (prior draws scored beside the prior's mean) must be an integer >= 0, got {starts!r}")
    if int(size) != size or size < MIN_SIZE:
        raise ValueError(f"size (rays compared per image side) must be an integer >= {MIN_SIZE}, got {size!r}")
    return RefineSettings(mode=mode, starts=int(starts), observation=ObservationSettings(size=int(size)), **knobs)


@dataclass
class Posterior:
    """The refined Gaussian N(mu [D], cov [D, D]) and how it was reached (record() for summary.json)."""

    mu: Tensor
    cov: Tensor
    iterations: int = 0
    energy_start: float = float("nan")
    energy_end: float = float("nan")
    rows: dict[str, int] = field(default_factory=dict)
    rms: dict[str, float] = field(default_factory=dict)
    fallback: str | None = None
    information: Tensor | None = None  # J^T W J [D, D] at the MAP (before information_scale), for fitting that scale
    views: list[dict[str, str | None]] = field(default_factory=list)  # per view: what it used, and why not more

    @property
    def var(self) -> Tensor:  # [D]
        return torch.diagonal(self.cov)

    def record(self) -> dict[str, Any]:
        return {
            "iterations": self.iterations,
            "energy_start": self.energy_start,
            "energy_end": self.energy_end,
            "rows": self.rows,
            "rms_residual": self.rms,
            "fallback": self.fallback,
            "trace_cov": float(self.var.sum()),
            "views": self.views,
        }


def prior_precision(var: Tensor) -> Tensor:
    """Sigma^-1 [D, D] of a diagonal var [D] or a full covariance [D, D], float64."""
    var = var.detach().double()
    if var.ndim == 1:
        if not bool((var > 0).all()):
            raise ValueError("the prior variance must be positive in every dimension")
        return torch.diag(1.0 / var)
    if var.ndim == 2 and var.shape[0] == var.shape[1]:
        return torch.linalg.inv(0.5 * (var + var.T))
    raise ValueError(f"the prior variance must be [D] or [D, D], got shape {tuple(var.shape)}")


def row_weights(res: Residuals, settings: RefineSettings) -> Tensor:
    """W [R]: 1 / sigma_mask^2 on silhouette rows, 1 / sigma_depth^2 Huber-down-weighted on the SDF-unit rows
    (depth returns and free space)."""
    sdf_rows = res.kind > 0
    w = torch.where(sdf_rows, 1.0 / settings.sigma_depth**2, 1.0 / settings.sigma_mask**2).double()
    huber = (settings.huber_depth / res.r.double().abs().clamp_min(1e-12)).clamp(max=1.0)
    return torch.where(sdf_rows, w * huber, w)


def information_matrix(res: Residuals, w: Tensor) -> Tensor:  # [D, D] float64
    """J^T W J of residuals `res` (their Jacobian filled in) under row weights w [R] (`row_weights`)."""
    J = res.J.double()
    return J.T @ (w[:, None] * J)


def energy(z: Tensor, mu: Tensor, precision: Tensor, res: Residuals, w: Tensor) -> float:
    dz = (z - mu).double()
    return float(0.5 * dz @ precision @ dz + 0.5 * (w * res.r.double().square()).sum())


def fallback(mu: Tensor, var: Tensor, reason: str, **known: Any) -> Posterior:
    """The prior as the posterior, with the reason logged."""
    log.warning("refinement fell back to the prior: %s", reason)
    cov = torch.diag(var.detach().float()) if var.ndim == 1 else var.detach().float()
    return Posterior(mu.detach().float().clone(), cov.clone(), fallback=reason, **known)


def _reasons(screened: Sequence[ScreenedView]) -> str:
    """'view 0: empty mask: ...; view 2: ...' for the views that gave nothing."""
    return "; ".join(f"view {i}: {s.fallback}" for i, s in enumerate(screened) if s.view is None)


def summarise(res: Residuals) -> tuple[dict[str, int], dict[str, float]]:
    rows, rms = {}, {}
    for kind, name in enumerate(KINDS):
        r = res.r[res.kind == kind]
        rows[name] = int(r.numel())
        rms[name] = float(r.square().mean().sqrt()) if r.numel() else float("nan")
    return rows, rms


def refine(
    decoder: torch.nn.Module,
    mu: Tensor,  # [D] the prior's mean (the fused code)
    var: Tensor,  # [D] or [D, D] the prior's variance
    views: Sequence[ObservedView | None],  # None: a view without a camera (not refined)
    settings: RefineSettings = RefineSettings(),
) -> Posterior:
    """MAP code and full-covariance Laplace posterior of the prior N(mu, var) given the views' masks (and depth)."""
    if settings.mode not in MODES:
        raise ValueError(f"refine mode must be one of {MODES}, got {settings.mode!r}")
    use_depth = settings.mode == "depth"
    screened = [screen_view(v, use_depth) for v in views]
    known: dict[str, Any] = {"views": [s.record() for s in screened]}
    for i, s in enumerate(screened):
        if s.fallback is not None:
            log.warning("view %d: %s", i, s.fallback if s.view is not None else f"{s.fallback}; not refined on")
    views = [s.view for s in screened if s.view is not None]
    if not views:
        if all(s.fallback == "no camera" for s in screened):
            return fallback(mu, var, "no view has a camera", **known)
        return fallback(mu, var, f"no view has a usable mask ({_reasons(screened)})", **known)
    if not any(bool((v.mask.reshape(-1)[v.seen().reshape(-1)] > 0.5).any()) for v in views):
        return fallback(mu, var, "no view shows the object (empty masks)", **known)
    precision = prior_precision(var)
    prior_mu = mu.detach().double()
    schedule = [
        replace(settings.observation, tau=settings.observation.tau * m) for m in settings.tau_schedule or (1.0,)
    ]
    with frozen(decoder):
        z = best_start(decoder, prior_mu, var, precision, views, settings, schedule[0], use_depth)
        known["iterations"] = 0
        for obs in schedule:
            z, res, w, energies, steps = levenberg_marquardt(
                decoder, prior_mu, z, precision, views, settings, obs, use_depth
            )
            known["iterations"] += steps
            known.setdefault("energy_start", energies[0])
            known["energy_end"] = energies[1]
            if res is None:
                return fallback(mu, var, "non-finite residual or Jacobian", **known)
        return laplace(prior_mu, var, z, precision, res, w, settings, known)


def best_start(
    decoder: torch.nn.Module,
    mu: Tensor,  # [D] float64
    var: Tensor,  # [D] or [D, D]
    precision: Tensor,  # [D, D] float64
    views: list[ObservedView],
    settings: RefineSettings,
    obs: ObservationSettings,
    use_depth: bool,
) -> Tensor:
    """The lowest-energy of the prior's mean and `settings.starts` draws from the prior [D] (float64)."""
    if settings.starts <= 0:
        return mu.clone()
    generator = torch.Generator().manual_seed(settings.seed)
    cov = torch.diag(var.double()) if var.ndim == 1 else var.double()
    root = torch.linalg.cholesky(0.5 * (cov + cov.T))
    draws = mu + torch.randn(settings.starts, mu.shape[0], generator=generator, dtype=torch.float64) @ root.T
    best, best_e = mu.clone(), float("inf")
    for z in torch.cat([mu[None], draws]):
        res = residuals(decoder, z.float(), views, obs, use_depth, jacobian=False)
        e = energy(z, mu, precision, res, row_weights(res, settings))
        if e < best_e:
            best, best_e = z.clone(), e
    return best


def levenberg_marquardt(
    decoder: torch.nn.Module,
    mu: Tensor,  # [D] float64, the prior's mean
    z: Tensor,  # [D] float64, the start
    precision: Tensor,  # [D, D] float64
    views: list[ObservedView],
    settings: RefineSettings,
    obs: ObservationSettings,
    use_depth: bool,
) -> tuple[Tensor, Residuals | None, Tensor | None, tuple[float, float], int]:
    """The damped Gauss-Newton loop of `refine` at one observation setting: (z, residuals and weights at z
    (None: non-finite), (energy at the start, at the end), steps)."""
    res = residuals(decoder, z.float(), views, obs, use_depth)
    w = row_weights(res, settings)
    start = e = energy(z, mu, precision, res, w)
    lam, steps = settings.damping, 0
    for steps in range(1, settings.iterations + 1):
        if not (torch.isfinite(res.r).all() and torch.isfinite(res.J).all()):
            return z, None, None, (start, e), steps
        J = res.J.double()
        H = precision + J.T @ (w[:, None] * J)
        g = precision @ (z - mu) + J.T @ (w * res.r.double())
        improved = False
        for _ in range(6):
            trial = z + torch.linalg.solve(H + lam * torch.diag(torch.diagonal(H)), -g)
            trial_res = residuals(decoder, trial.float(), views, obs, use_depth, jacobian=False)
            trial_w = row_weights(trial_res, settings)
            trial_e = energy(trial, mu, precision, trial_res, trial_w)
            if trial_e < e:  # NaN compares False: a non-finite trial is rejected like a worse one
                improved = True
                break
            lam *= 4.0
        if not improved:
            break
        # The Jacobian only where a step is taken: a rejected trial costs its residuals alone.
        z, res, w, lam = trial, with_jacobian(decoder, trial.float(), trial_res), trial_w, max(lam / 3.0, 1e-7)
        done = (e - trial_e) < settings.tolerance * max(e, 1e-12)
        e = trial_e
        if done:
            break
    return z, res, w, (start, e), steps


def laplace(
    mu: Tensor,  # [D] float64, the prior's mean
    var: Tensor,
    z: Tensor,  # [D] float64, the MAP
    precision: Tensor,  # [D, D] float64
    res: Residuals,
    w: Tensor,  # [R]
    settings: RefineSettings,
    known: dict[str, Any],
) -> Posterior:
    """N(z, (Sigma^-1 + J^T W J)^-1) at the MAP, or the prior when it is non-finite or diverged."""
    information = information_matrix(res, w)
    cov = torch.linalg.inv(precision + settings.information_scale * information)
    cov = 0.5 * (cov + cov.T)
    distance = float(torch.sqrt((z - mu) @ precision @ (z - mu)))
    rows, rms = summarise(res)
    known = dict(known, rows=rows, rms=rms, information=information)
    if not (torch.isfinite(z).all() and torch.isfinite(cov).all()):
        return fallback(mu, var, "non-finite code or covariance", **known)
    if distance > settings.max_mahalanobis:
        return fallback(mu, var, f"diverged ({distance:.1f} prior stds from the fused code)", **known)
    return Posterior(z.float(), cov.float(), **known)
