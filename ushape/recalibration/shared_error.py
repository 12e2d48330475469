"""The error every view of a shape shares, fitted on val: S [D] and the views' own scale c, in latent space.

Model: view v of shape s predicts mu_sv with error e_sv = mu_sv - z_s = e_s + e_sv', where e_s ~ N(0, S)
is the same for all views of the shape and e_sv' ~ N(0, c var_sv) is the view's own. Then, for two
different views of one shape, E[e_sv e_sw] = S (per dimension): S is the mean over shapes of the mean
cross-view product, ((sum_v e_v)^2 - sum_v e_v^2) / (V (V - 1)), floored at 0. From a val split of 10
shapes that estimate is noisy per dimension (measured: it correlates 0.2-0.3 with the same estimate on the
test shapes), so by default only its trace is kept, spread over the dimensions like the views' mean
variance ("proportional": S = s mean_v var_v, one number fitted); "diagonal" keeps every dimension's
own estimate (docs/fusion_calibration.md). Given S, c minimises the
Gaussian NLL of the single views' errors under N(0, S + c var), so one view stays as calibrated as the
temperature left it. `ushape.fusion.SharedErrorFusion` fuses with S + c (sum_v var_v^-1)^-1. The rule's own
SDF calibration (its fused variance propagated to SDF values: a factor, a floor and a term in the distance
from the predicted surface, fitted on val fused 1, 3 and 10 views at a time) is fitted by
`ushape.reconstruction.temperature_store` and kept here beside S.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import torch
from torch import Tensor

STRUCTURES = ("proportional", "diagonal")

# Per-view scales c tried: 2^(k/32) from 1/256 to 4; the NLL is then refined by golden-section search.
SCALE_RANGE = (-8.0, 2.0)


@dataclass(frozen=True)
class SharedError:
    """A fitted shared error: S [D] (variance per latent dimension), the views' own scale c, shapes used,
    and the SDF calibration of the rule's fused SDF variance, T var + floor^2 + (b |clamp(mean)|)^2: its
    temperature T, floor and distance scale b (`ushape.recalibration.sdf_distance`; None where not fitted)."""

    shared_var: Tensor  # [D]
    view_scale: float
    n_shapes: int
    sdf_temperature: float | None = None
    structure: str = "diagonal"  # how S was spread over the dimensions (STRUCTURES)
    sdf_floor: float | None = None  # the decoder's own SDF misfit (std), added to the fused SDF variance
    sdf_distance_scale: float | None = None  # b: the std that grows with the distance from the surface

    def to_record(self) -> dict[str, Any]:
        record = {"var": self.shared_var.tolist(), "view_scale": self.view_scale, "n_shapes": self.n_shapes}
        record["structure"] = self.structure
        if self.sdf_floor is not None:
            record["sdf_floor"] = self.sdf_floor
        if self.sdf_distance_scale is not None:
            record["sdf_distance_scale"] = self.sdf_distance_scale
        return record if self.sdf_temperature is None else {**record, "sdf_temperature": self.sdf_temperature}

    @staticmethod
    def from_record(record: dict[str, Any]) -> SharedError:
        sdf = record.get("sdf_temperature")
        return SharedError(
            torch.tensor(record["var"], dtype=torch.float32),
            float(record["view_scale"]),
            int(record["n_shapes"]),
            None if sdf is None else float(sdf),
            str(record.get("structure", "diagonal")),
            None if record.get("sdf_floor") is None else float(record["sdf_floor"]),
            None if record.get("sdf_distance_scale") is None else float(record["sdf_distance_scale"]),
        )


def group_index(groups: Sequence[str] | Tensor) -> Tensor:
    """One integer per sample [N] (0..G-1, in order of first appearance) from shape ids or integers."""
    if isinstance(groups, Tensor):
        groups = groups.tolist()
    ids: dict = {}
    return torch.tensor([ids.setdefault(g, len(ids)) for g in groups], dtype=torch.long)


def shared_variance(
    error: Tensor,  # [N, D]
    groups: Sequence[str] | Tensor,  # [N]
) -> tuple[Tensor, int]:
    """(S [D], shapes used): the mean over shapes with >= 2 views of the mean cross-view product of errors."""
    index = group_index(groups)
    if index.shape[0] != error.shape[0]:
        raise ValueError(f"{index.shape[0]} group labels for {error.shape[0]} errors: pass one shape id per view")
    error = error.double()
    n_groups = int(index.max()) + 1 if index.numel() else 0
    count = torch.bincount(index, minlength=n_groups).double()
    total = torch.zeros(n_groups, error.shape[1], dtype=torch.float64).index_add_(0, index, error)
    squares = torch.zeros_like(total).index_add_(0, index, error.square())
    usable = count >= 2
    if not usable.any():
        raise ValueError("no shape has two or more views: the shared error needs several views of one shape")
    pairs = (count * (count - 1))[usable].unsqueeze(-1)
    cross = (total[usable].square() - squares[usable]) / pairs
    return cross.mean(dim=0).clamp(min=0.0), int(usable.sum())


def proportional_shared_variance(
    shared: Tensor,  # [D] the per-dimension cross-view estimate
    var: Tensor,  # [N, D] the views' variances
) -> Tensor:
    """S [D] = s mean_n var_n with s such that S keeps the estimate's trace: one number fitted, not D."""
    mean_var = var.double().mean(dim=0)
    return mean_var * (shared.double().sum() / mean_var.sum())


def view_nll(error: Tensor, var: Tensor, shared: Tensor, scale: float) -> float:
    """Mean Gaussian NLL per dimension of error [N, D] under N(0, S + c var) (constant dropped)."""
    total = shared + scale * var
    return float((0.5 * (total.log() + error.square() / total)).mean())


def fit_view_scale(error: Tensor, var: Tensor, shared: Tensor, steps: int = 60) -> float:
    """The c minimising `view_nll`: a grid over log2 c, then golden-section search around its best point."""
    error, var, shared = error.double(), var.double(), shared.double()
    grid = torch.linspace(SCALE_RANGE[0], SCALE_RANGE[1], 321, dtype=torch.float64)
    scores = [view_nll(error, var, shared, 2.0 ** float(g)) for g in grid]
    best = int(torch.tensor(scores).argmin())
    low, high = float(grid[max(best - 1, 0)]), float(grid[min(best + 1, len(grid) - 1)])
    ratio = (math.sqrt(5) - 1) / 2
    for _ in range(steps):
        a, b = high - ratio * (high - low), low + ratio * (high - low)
        if view_nll(error, var, shared, 2.0**a) < view_nll(error, var, shared, 2.0**b):
            high = b
        else:
            low = a
    return 2.0 ** ((low + high) / 2)


def fit_shared_error(
    mu: Tensor,  # [N, D]
    var: Tensor,  # [N, D], temperature-scaled as the fused views will be
    target: Tensor,  # [N, D]
    groups: Sequence[str] | Tensor,  # [N] the shape each view shows
    structure: str = "proportional",
) -> SharedError:
    """S [D] and c of the model e_v = e_shape + e_view, from several views of each val shape; S spread over the
    dimensions as `structure` says (STRUCTURES)."""
    if structure not in STRUCTURES:
        raise ValueError(f"structure must be one of {STRUCTURES}, got {structure!r}")
    if not (mu.shape == var.shape == target.shape) or mu.ndim != 2:
        raise ValueError(
            f"mu {tuple(mu.shape)}, var {tuple(var.shape)} and target {tuple(target.shape)} must share one shape [N, D]"
        )
    for name, t in (("mu", mu), ("var", var), ("target", target)):
        if not torch.isfinite(t).all():
            raise ValueError(f"{name} holds NaN/inf values; clean the validation set before fitting S")
    if (var <= 0).any():
        raise ValueError("var must be > 0 everywhere (a variance, not a log-variance)")
    error = mu.double() - target.double()
    shared, n_shapes = shared_variance(error, groups)
    if structure == "proportional":
        shared = proportional_shared_variance(shared, var)
    scale = fit_view_scale(error, var.double(), shared)
    return SharedError(shared.float(), scale, n_shapes, structure=structure)
