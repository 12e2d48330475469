"""Stage-2 training losses in latent space: the encoder predicts N(mu, diag(exp(logvar))) for code z.

All three share the signature `(mu, logvar, target, **params) -> scalar` so the loss config group
can swap them with a Hydra `_partial_`; each returns the mean over the batch of a per-sample score.
"""

from __future__ import annotations

from typing import Callable

import torch
from torch import Tensor


def _check(mu: Tensor, logvar: Tensor | None, target: Tensor) -> None:
    if mu.ndim != 2 or mu.shape != target.shape or (logvar is not None and logvar.shape != mu.shape):
        shapes = (tuple(mu.shape), None if logvar is None else tuple(logvar.shape), tuple(target.shape))
        raise ValueError(f"mu, logvar, target must all be [B, D]; got {shapes}")


def energy_score_from_samples(samples: Tensor, target: Tensor) -> Tensor:
    """The paper's Monte Carlo Energy Score, batch mean. samples [B, M, D], target [B, D] -> scalar.

    Per sample: (1/M) sum_m ||z_m - z|| - 1/(2(M-1)) sum_{m<M} ||z_m - z_{m+1}||, Euclidean norms.
    The second term pairs consecutive draws only, an unbiased estimate of E||Z - Z'|| / 2 in O(M).
    """
    if samples.ndim != 3 or samples.shape[0] != target.shape[0] or samples.shape[2] != target.shape[1]:
        raise ValueError(
            f"samples must be [B, M, D] for target [B, D]; got {tuple(samples.shape)}, {tuple(target.shape)}"
        )
    m = samples.shape[1]
    if m < 2:
        raise ValueError("the Energy Score needs at least 2 samples per prediction (n_samples >= 2)")
    accuracy = (samples - target[:, None, :]).norm(dim=-1).mean(dim=1)
    spread = (samples[:, 1:] - samples[:, :-1]).norm(dim=-1).sum(dim=1) / (2 * (m - 1))
    return (accuracy - spread).mean()


def energy_score(
    mu: Tensor,  # [B, D]
    logvar: Tensor,  # [B, D]
    target: Tensor,  # [B, D]
    n_samples: int = 1000,
    generator: torch.Generator | None = None,
) -> Tensor:
    """Energy Score of N(mu, diag(exp(logvar))) at target, batch mean, by M reparameterised draws.

    z_m = mu + exp(logvar / 2) * eps_m, so the gradient reaches both mu and logvar.
    """
    _check(mu, logvar, target)
    eps = torch.randn((mu.shape[0], n_samples, mu.shape[1]), generator=generator, device=mu.device, dtype=mu.dtype)
    samples = mu[:, None, :] + torch.exp(0.5 * logvar)[:, None, :] * eps
    return energy_score_from_samples(samples, target)


def gaussian_nll(mu: Tensor, logvar: Tensor, target: Tensor) -> Tensor:
    """The paper's NLL, batch mean: (1/2N) sum_i [(mu_i - z_i)^T Sigma_i^-1 (mu_i - z_i) + log det Sigma_i].

    mu, logvar, target [B, D] -> scalar. It leaves out the constant 0.5 * D * log(2 pi), so it equals
    the true negative log-likelihood -log N(z; mu, Sigma) minus 0.5 * D * log(2 pi) (D = 64: 58.81).
    """
    _check(mu, logvar, target)
    per_sample = ((mu - target) ** 2 * torch.exp(-logvar) + logvar).sum(dim=-1)
    return 0.5 * per_sample.mean()


def l2_loss(mu: Tensor, logvar: Tensor | None, target: Tensor) -> Tensor:
    """FroDO*'s deterministic baseline: mean over batch and dimensions of (mu - z)^2; logvar is unused."""
    _check(mu, None, target)
    return ((mu - target) ** 2).mean()


def ensemble_loss(
    loss_fn: Callable[..., Tensor],
    mus: Tensor,  # [E, B, D]
    logvars: Tensor,  # [E, B, D]
    target: Tensor,  # [B, D]
    member_of: Tensor,  # bool [E, B]
    cross_fit: bool = False,
) -> Tensor:
    """Mean over the E members of `loss_fn` on each member's share of the batch (GaussianEnsemble).

    Plain: member e fits its mean and variance on the rows it trains on (member_of[e]). A head
    fitted on shapes it has memorised learns their small, in-sample residuals, so its variance
    says little about a new shape. With `cross_fit`, member e's mean still fits its own rows
    (its variance held fixed there), while its variance fits the other rows, against its own mean
    held fixed: residuals of shapes that mean has never seen, i.e. the errors it makes on new ones.
    A member with no row of a kind in this batch stays in the graph with weight 0 (DDP).
    """
    if mus.ndim != 3 or logvars.shape != mus.shape or target.shape != mus.shape[1:]:
        raise ValueError(
            f"mus, logvars must be [E, B, D] and target [B, D]; got "
            f"{tuple(mus.shape)}, {tuple(logvars.shape)}, {tuple(target.shape)}"
        )
    if member_of.shape != mus.shape[:2] or member_of.dtype != torch.bool:
        raise ValueError(f"member_of must be bool [E, B] = {tuple(mus.shape[:2])}, got {tuple(member_of.shape)}")
    losses = []
    for mu, logvar, rows in zip(mus, logvars, member_of):
        if not cross_fit:
            if rows.any():
                losses.append(loss_fn(mu[rows], logvar[rows], target[rows]))
            continue
        member = [loss_fn(mu[rows], logvar[rows].detach(), target[rows])] if rows.any() else []
        if (~rows).any():
            member.append(loss_fn(mu[~rows].detach(), logvar[~rows], target[~rows]))
        if member:
            losses.append(torch.stack(member).sum())
    total = torch.stack(losses).mean() if losses else mus.sum() * 0.0
    return total + 0.0 * (mus.sum() + logvars.sum())
