"""Fusion rules as configurable callables for the Hydra `fusion` group (`_target_` builds them)."""

from __future__ import annotations

from torch import Tensor

from ushape.fusion.incremental import IncrementalFuser
from ushape.fusion.rules import FusedCode, check_k, fuse_average, fuse_bayesian, fuse_bayesian_k


class AverageFusion:
    """FroDO*'s equal-weight average of the views' codes."""

    name = "average"

    def __call__(self, mu: Tensor, var: Tensor) -> FusedCode:
        """mu, var [..., V, D] -> fused code [..., D]."""
        return fuse_average(mu, var)

    def incremental(self) -> IncrementalFuser:
        return IncrementalFuser("average")


class BayesianFusion:
    """Product of all views' Gaussians (the paper's "Bayesian")."""

    name = "bayesian"

    def __init__(self, var_floor: float = 1e-8) -> None:
        if var_floor <= 0:
            raise ValueError(f"var_floor must be > 0, got {var_floor}")
        self.var_floor = var_floor

    def __call__(self, mu: Tensor, var: Tensor) -> FusedCode:
        """mu, var [..., V, D] -> fused code [..., D]."""
        return fuse_bayesian(mu, var, self.var_floor)

    def incremental(self) -> IncrementalFuser:
        return IncrementalFuser("bayesian", var_floor=self.var_floor)


class BayesianKFusion:
    """Product of the K least uncertain views (the paper's "Bayesian-N" outlier rejection)."""

    def __init__(self, k: int, var_floor: float = 1e-8) -> None:
        k = check_k(k)
        if var_floor <= 0:
            raise ValueError(f"var_floor must be > 0, got {var_floor}")
        self.k = k
        self.var_floor = var_floor
        self.name = f"bayesian-{k}"

    def __call__(self, mu: Tensor, var: Tensor) -> FusedCode:
        """mu, var [..., V, D] -> fused code [..., D] from the K lowest-trace views."""
        return fuse_bayesian_k(mu, var, self.k, self.var_floor)

    def incremental(self) -> IncrementalFuser:
        return IncrementalFuser("bayesian_k", k=self.k, var_floor=self.var_floor)
