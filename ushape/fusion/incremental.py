"""Streaming fusion: add one view's latent Gaussian at a time, read the fused code at any point."""

from __future__ import annotations

import torch
from torch import Tensor

from ushape.fusion.rules import FusedCode, check_k, check_views, product_of_gaussians

RULES = ("average", "bayesian", "bayesian_k")


class IncrementalFuser:
    """Fuses views as they arrive; `result()` equals the batch rule on all views added so far.

    average and bayesian keep running sums (O(D) memory); bayesian_k keeps the K views with
    the lowest covariance trace seen so far. Until K views have arrived, bayesian_k fuses all
    of them (the batch rule does the same, with a warning).
    """

    def __init__(self, rule: str = "bayesian", k: int | None = None, var_floor: float = 1e-8) -> None:
        if rule not in RULES:
            raise ValueError(f"unknown fusion rule {rule!r}; choose one of {RULES}")
        if rule == "bayesian_k":
            if k is None:
                raise ValueError("rule 'bayesian_k' needs an integer k >= 1 (views to keep), got None")
            k = check_k(k)
        if var_floor <= 0:
            raise ValueError(f"var_floor must be > 0, got {var_floor}")
        self.rule = rule
        self.k = k
        self.var_floor = var_floor
        self.n_views = 0
        self._first: tuple[Tensor, Tensor] | None = None
        self._sum_a: Tensor | None = None  # average: sum mu_i; bayesian: sum Sigma_i^-1
        self._sum_b: Tensor | None = None  # average: sum var_i; bayesian: sum Sigma_i^-1 mu_i
        self._best: list[tuple[int, Tensor, Tensor]] = []  # bayesian_k: (view index, mu, var)

    def add(self, mu: Tensor, var: Tensor) -> None:
        """Fold in one view's Gaussian over the latent code: mu [D], var [D]."""
        if mu.ndim != 1:
            raise ValueError(f"add() takes one view: mu of shape [D], got {tuple(mu.shape)}")
        try:
            check_views(mu.unsqueeze(0), var.unsqueeze(0))
        except ValueError as err:
            # check_views numbers views within its own stack; here there is only this one.
            reason = str(err).replace(" in view(s) [0]", "")
            raise ValueError(f"view {self.n_views} (0-based, in order of add): {reason}") from None
        if self._first is not None and mu.shape != self._first[0].shape:
            raise ValueError(
                f"view {self.n_views} has latent size {mu.shape[0]}, earlier views {self._first[0].shape[0]}"
            )
        index = self.n_views
        self.n_views += 1
        if self._first is None:
            self._first = (mu.detach().clone(), var.detach().clone())
        if self.rule == "average":
            self._accumulate(mu, var)
        elif self.rule == "bayesian":
            information = var.clamp(min=self.var_floor).reciprocal()
            self._accumulate(information, information * mu)
        else:
            self._keep_if_better(index, mu.detach().clone(), var.detach().clone())

    def _accumulate(self, a: Tensor, b: Tensor) -> None:
        if self._sum_a is None:
            self._sum_a, self._sum_b = a.detach().clone(), b.detach().clone()
        else:
            self._sum_a = self._sum_a + a.detach()
            self._sum_b = self._sum_b + b.detach()

    def _keep_if_better(self, index: int, mu: Tensor, var: Tensor) -> None:
        if len(self._best) < self.k:
            self._best.append((index, mu, var))
            return
        # The worst kept view: largest trace, and among equal traces the latest (the batch
        # rule's stable sort prefers earlier views), so a tie never evicts anyone.
        worst = max(range(len(self._best)), key=lambda i: (float(self._best[i][2].sum()), self._best[i][0]))
        if float(var.sum()) < float(self._best[worst][2].sum()):
            self._best[worst] = (index, mu, var)

    def result(self) -> FusedCode:
        """The fused Gaussian over the latent code from every view added so far."""
        if self._first is None:
            raise ValueError("no views added yet: call add(mu, var) at least once before result()")
        if self.rule == "bayesian_k":
            best = sorted(self._best, key=lambda item: item[0])
            mu = torch.stack([item[1] for item in best])
            var = torch.stack([item[2] for item in best])
            fused_mu, fused_var = product_of_gaussians(mu, var, self.var_floor)
            return FusedCode(fused_mu, fused_var, torch.tensor([item[0] for item in best]))
        kept = torch.arange(self.n_views)
        if self.n_views == 1 and self.rule == "bayesian":
            mu, var = self._first
            return FusedCode(mu.clone(), var.clamp(min=self.var_floor), kept)
        if self.rule == "average":
            return FusedCode(self._sum_a / self.n_views, self._sum_b / self.n_views / self.n_views, kept)
        fused_var = self._sum_a.reciprocal()
        return FusedCode(fused_var * self._sum_b, fused_var, kept)
