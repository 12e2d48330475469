"""Next-view strategies: each scores every candidate from the loop's state (`PlanState`), higher is better.

- uncertainty: the uncertain surface a candidate would see of the current mesh (the paper's proposed use).
- unseen-uncertainty: the same over the surface no view taken so far has seen.
- farthest: the candidate farthest (in angle about the object) from every view taken; geometry only.
- random: a uniformly random candidate (reproducible per shape and step).
- information: the expected information gain of a candidate's silhouette (or depth), predicted at the
  current mean through its camera, under the current covariance (ushape.planning.information).
- information-surface: the same predicted rows scored by the SDF variance they would take off the current
  surface, area-weighted, rather than by the log det over every code direction.
- information-seen: information-surface on the variance the refined mesh is drawn with under the run's fitted
  seen model (a floor where a view saw the surface, a larger one where none did), so a candidate also gains
  for the unseen surface it would show (`reconstruct.py --fit-refinement` fits the floors).
- oracle: the candidate whose image brings the fused code closest to the shape's own code. It looks at
  every candidate's image and at the answer, so it is no strategy a robot could run: it bounds how much
  any choice of views can give with this encoder.
"""

from __future__ import annotations

import zlib

import numpy as np
import torch
from torch import Tensor

from ushape.planning.criteria import angular_gap, uncertain_surface, unseen_uncertain_surface
from ushape.planning.information import (
    INFORMATION_STRATEGIES,
    InformationGain,
    SeenInformationGain,
    SurfaceInformationGain,
)
from ushape.planning.loop import Encode, Fusion, PlanState


class FarthestView:
    name = "farthest"

    def scores(self, state: PlanState) -> np.ndarray:
        return angular_gap(state.candidates.directions, state.taken)


class RandomView:
    name = "random"

    def __init__(self, seed: int = 0) -> None:
        self.seed = seed

    def scores(self, state: PlanState) -> np.ndarray:
        key = [self.seed, zlib.crc32(state.candidates.shape_id.encode()), len(state.taken)]
        return np.random.default_rng(key).random(len(state.candidates))


class UncertainSurface:
    """Sum of SDF variance x area over the mesh vertices a candidate sees. Where the fused code has no
    surface there is nothing to score, and the farthest view is taken instead."""

    name = "uncertainty"

    def scores(self, state: PlanState) -> np.ndarray:
        surface = state.surface
        if surface is None:
            return FarthestView().scores(state)
        return uncertain_surface(surface.visible, surface.variance, surface.area)


class UnseenUncertainSurface:
    """`UncertainSurface` over the vertices that no view taken so far sees; once every candidate's unseen
    part is empty (or there is no surface), the farthest view."""

    name = "unseen-uncertainty"

    def scores(self, state: PlanState) -> np.ndarray:
        surface = state.surface
        if surface is None:
            return FarthestView().scores(state)
        score = unseen_uncertain_surface(surface.visible, surface.variance, surface.area, surface.seen)
        open_scores = np.delete(score, state.taken)
        return score if open_scores.size and open_scores.max() > 0 else FarthestView().scores(state)


def distances_with_each(
    encode: Encode, fusion: Fusion, taken: list[int], n_candidates: int, true_code: Tensor
) -> np.ndarray:  # [C]
    """Distance from the fused code of the views taken plus candidate c to true_code, per candidate (inf where
    taken). It encodes every open candidate: only the oracle and the evaluation's diagnostics look this far."""
    encoded = [encode(i) for i in taken]
    distances = np.full(n_candidates, np.inf)
    for c in range(n_candidates):
        if c in taken:
            continue
        mu, var = zip(*encoded, encode(c))
        distances[c] = float((fusion(torch.stack(mu), torch.stack(var)).mu - true_code).norm())
    return distances


class LatentOracle:
    """Minus the distance from the fused code (views taken plus the candidate) to the shape's own code."""

    name = "oracle"

    def __init__(self, true_code: Tensor) -> None:
        self.true_code = true_code.float()

    def scores(self, state: PlanState) -> np.ndarray:
        return -distances_with_each(state.encode, state.fusion, state.taken, len(state.candidates), self.true_code)


STRATEGIES = {
    s.name: s
    for s in (
        UncertainSurface,
        UnseenUncertainSurface,
        FarthestView,
        RandomView,
        InformationGain,
        SurfaceInformationGain,
        SeenInformationGain,
    )
}  # what a robot can run; the oracle needs the answer


def build_strategy(name: str, seed: int = 0, true_code: Tensor | None = None, **options):
    """A strategy by name (one of STRATEGIES, or "oracle" given the shape's own code); options go to the
    information strategies (their rays per side `size`, the residuals' stds)."""
    if name == LatentOracle.name:
        if true_code is None:
            raise ValueError("the oracle strategy needs the shape's own code (it scores against the answer)")
        return LatentOracle(true_code)
    if name not in STRATEGIES:
        raise ValueError(f"unknown strategy {name!r}; choose one of {[*STRATEGIES, LatentOracle.name]}")
    if name in INFORMATION_STRATEGIES:
        return STRATEGIES[name](**options)
    return RandomView(seed) if name == RandomView.name else STRATEGIES[name]()
