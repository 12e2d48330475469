"""Fusion rules as configurable callables for the Hydra `fusion` group (`_target_` builds them)."""

from __future__ import annotations

import math
from typing import Sequence

import torch
from torch import Tensor

from ushape.fusion.incremental import IncrementalFuser
from ushape.fusion.rules import FusedCode, check_k, fuse_average, fuse_bayesian, fuse_bayesian_k
from ushape.fusion.shared import add_shared, check_shared, fuse_intersection, fuse_shared, fuse_shared_k


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


class SharedIncremental:
    """Streaming `SharedErrorFusion`: Bayesian's (or Bayesian-K's) running product, with S + c var read out."""

    def __init__(self, inner: IncrementalFuser, shared_var: Tensor, view_scale: float) -> None:
        self.inner, self.shared_var, self.view_scale = inner, shared_var, view_scale

    @property
    def n_views(self) -> int:
        return self.inner.n_views

    def add(self, mu: Tensor, var: Tensor) -> None:
        """Fold in one view's Gaussian over the latent code: mu [D], var [D]."""
        self.inner.add(mu, var)

    def result(self) -> FusedCode:
        return add_shared(self.inner.result(), self.shared_var, self.view_scale)


def check_optional_number(value, name: str, zero_ok: bool = False) -> float | None:
    """None, or value as a float; a ValueError naming it unless finite and > 0 (>= 0 with zero_ok)."""
    if value is None:
        return None
    bound = ">= 0" if zero_ok else "> 0"
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number {bound} or None, got {value!r}") from None
    if not (math.isfinite(number) and (number >= 0 if zero_ok else number > 0)):
        raise ValueError(f"{name} must be a finite number {bound} or None, got {value!r}")
    return number


def check_sdf_temperature(value) -> float | None:
    """None, or the factor on a rule's propagated SDF variance as a float; a ValueError if not finite and > 0."""
    return check_optional_number(value, "sdf_temperature")


class SharedErrorFusion:
    """Bayesian fusion that keeps the error all views of a shape share: var = S + c (sum_v var_v^-1)^-1.

    S [D] and c are fitted on val beside the temperature (`python reconstruct.py --fit-temperature`)
    and apply to temperature-scaled view variances; `calibrated(S, c)` gives the rule with them.
    With k, only the K lowest-trace views are fused, chosen exactly as Bayesian-K chooses them.
    sdf_temperature: the factor on this rule's fused variance once propagated to SDF values (fitted on
    val beside S; None: whoever propagates it applies the single-view SDF temperature). sdf_floor: the
    decoder's own SDF misfit (a std, measured on val at the shapes' own codes), added to that variance.
    sdf_distance_scale: b, a std that grows with the clamped mean SDF's distance from the surface, where the
    fused error grows (`ushape.recalibration.sdf_distance`): T var + floor^2 + (b |mean|)^2 (None: no term).
    """

    def __init__(
        self,
        shared_var: Sequence[float] | Tensor | None = None,
        view_scale: float = 1.0,
        k: int | None = None,
        var_floor: float = 1e-8,
        source: str | None = None,
        sdf_temperature: float | None = None,
        sdf_floor: float | None = None,
        sdf_distance_scale: float | None = None,
    ) -> None:
        if var_floor <= 0:
            raise ValueError(f"var_floor must be > 0, got {var_floor}")
        self.k = None if k is None else check_k(k)
        self.sdf_temperature = check_sdf_temperature(sdf_temperature)
        self.sdf_floor = check_optional_number(sdf_floor, "sdf_floor", zero_ok=True)
        self.sdf_distance_scale = check_optional_number(sdf_distance_scale, "sdf_distance_scale", zero_ok=True)
        # What a summary says about the fit: where S and c came from (None until fitted).
        fitted = (
            "shared error S, view scale c"
            + ("" if self.sdf_temperature is None else f" and SDF factor {self.sdf_temperature:.3g}")
            + ("" if self.sdf_floor is None else f" (SDF floor {self.sdf_floor:.3g})")
            + ("" if self.sdf_distance_scale is None else f" (SDF distance scale {self.sdf_distance_scale:.3g})")
        )
        self.calibration = None if shared_var is None else f"{fitted} fitted on val: {source}"
        self.shared_var = None if shared_var is None else torch.as_tensor(shared_var, dtype=torch.float32)
        self.view_scale = float(view_scale)
        if self.shared_var is not None:
            check_shared(self.shared_var, self.view_scale, self.shared_var.shape[-1])
        self.var_floor = var_floor
        self.name = "shared" if self.k is None else f"shared-{self.k}"

    def calibrated(
        self,
        shared_var: Sequence[float] | Tensor,
        view_scale: float,
        source: str | None = None,
        sdf_temperature: float | None = None,
        sdf_floor: float | None = None,
        sdf_distance_scale: float | None = None,
    ) -> SharedErrorFusion:
        """This rule with a fitted shared error S [D], per-view scale c and SDF calibration (temperature, floor,
        distance scale; `source`: where they were read)."""
        sdf = (sdf_temperature, sdf_floor, sdf_distance_scale)
        return SharedErrorFusion(shared_var, view_scale, self.k, self.var_floor, source, *sdf)

    def _fit(self) -> Tensor:
        if self.shared_var is None:
            raise ValueError(
                "fusion 'shared' needs the shared error S fitted on val: run `python reconstruct.py --fit-temperature` "
                "for this run (it stores S beside the temperature), or pick another fusion rule"
            )
        return self.shared_var

    def __call__(self, mu: Tensor, var: Tensor) -> FusedCode:
        """mu, var [..., V, D] -> fused code [..., D]."""
        shared = self._fit()
        if self.k is None:
            return fuse_shared(mu, var, shared, self.view_scale, self.var_floor)
        return fuse_shared_k(mu, var, shared, self.k, self.view_scale, self.var_floor)

    def incremental(self) -> SharedIncremental:
        shared = self._fit()
        inner = (
            IncrementalFuser("bayesian", var_floor=self.var_floor)
            if self.k is None
            else IncrementalFuser("bayesian_k", k=self.k, var_floor=self.var_floor)
        )
        return SharedIncremental(inner, shared, self.view_scale)


class CovarianceIntersectionFusion:
    """Covariance intersection with equal weights: Bayesian's mean, the views' harmonic-mean variance."""

    name = "intersection"

    def __init__(self, var_floor: float = 1e-8) -> None:
        if var_floor <= 0:
            raise ValueError(f"var_floor must be > 0, got {var_floor}")
        self.var_floor = var_floor

    def __call__(self, mu: Tensor, var: Tensor) -> FusedCode:
        """mu, var [..., V, D] -> fused code [..., D]."""
        return fuse_intersection(mu, var, self.var_floor)
