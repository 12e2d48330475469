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
- oracle: the candidate whose image brings the loop's belief closest to the shape's own code: the fused code,
  or, under a refining observer, the belief refined on the views taken plus that candidate (exactly what the
  loop's next step would believe). It looks at every candidate's image and at the answer, so it is no
  strategy a robot could run: the greedy choice by the latent distance.
- oracle-occupancy: the same, by the shape: the belief's occupancy against the own code's at fixed points
  (1 - IoU). What a greedy choice of views can give where the score is the shape, not the code.

Each is named by its file conf/strategy/<name>.yaml (see planning.plugins), which builds its class.
"""

from __future__ import annotations

import zlib
from typing import Callable

import numpy as np
import torch
from torch import Tensor

from ushape.decoder.query import code_sdf_fn
from ushape.fusion.rules import FusedCode
from ushape.metrics.reconstruction import EmptyOccupancyError, iou_from_occupancy, sdf_inside_fn
from ushape.planning.criteria import angular_gap, uncertain_surface, unseen_uncertain_surface
from ushape.planning.loop import Encode, Fusion, PlanState

Belief = Callable[[FusedCode, list[int]], FusedCode]  # (the fused Gaussian of views, those views) -> the belief


class FarthestView:
    name = "farthest"

    def scores(self, state: PlanState) -> np.ndarray:
        return angular_gap(state.candidates.directions, state.taken)


class RandomView:
    name = "random"

    def __init__(self, seed: int = 0) -> None:
        self.seed = seed

    @classmethod
    def for_sequence(cls, context, **settings):
        return cls(**{"seed": context.seed, **settings})

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
    encode: Encode,
    fusion: Fusion,
    taken: list[int],
    n_candidates: int,
    distance: Callable[[FusedCode], float],
    belief: Belief | None = None,
) -> np.ndarray:  # [C]
    """`distance` of the belief of the views taken plus candidate c, per candidate (inf where taken): of their
    fused code, or of `belief` of it (a refinement on those views). It encodes every open candidate: only the
    oracles and the evaluation's diagnostics look this far."""
    encoded = [encode(i) for i in taken]
    distances = np.full(n_candidates, np.inf)
    for c in range(n_candidates):
        if c in taken:
            continue
        mu, var = zip(*encoded, encode(c))
        code = fusion(torch.stack(mu), torch.stack(var))
        if belief is not None:
            code = belief(code, [*taken, c])
        distances[c] = distance(code)
    return distances


def code_distance(true_code: Tensor) -> Callable[[FusedCode], float]:
    """A belief -> the Euclidean distance of its mean from the shape's own code."""
    return lambda code: float((code.mu.float() - true_code).norm())


class LatentOracle:
    """Minus the distance to the shape's own code of the belief after the views taken plus the candidate: their
    fused code, or with the loop's `observer` (ushape.planning.observers) what it makes of that code: the code
    itself (none), or its refinement on those views, which costs one refinement per open candidate."""

    name = "oracle"
    oracle = True  # it looks at the answer

    def __init__(self, true_code: Tensor, observer=None) -> None:
        self.true_code, self.observer = true_code.float(), observer

    @classmethod
    def for_sequence(cls, context, **settings):
        if context.true_code is None:
            raise ValueError(f"the {cls.name} strategy needs the shape's own code (it scores against the answer)")
        return cls(context.true_code, **{"observer": context.observer, **settings})

    def distance(self, state: PlanState) -> Callable[[FusedCode], float]:
        return code_distance(self.true_code)

    def scores(self, state: PlanState) -> np.ndarray:
        belief = None
        if self.observer is not None:
            view_of = getattr(state.encode, "observed", state.candidates.observed)

            def belief(fused: FusedCode, views: list[int]) -> FusedCode:
                return self.observer(state.decoder, fused, views, view_of)[0]

        n = len(state.candidates)
        return -distances_with_each(state.encode, state.fusion, state.taken, n, self.distance(state), belief)


def occupancy_iou(
    inside: np.ndarray,  # [P] bool
    reference: np.ndarray,  # [P] bool
) -> float:
    """The IoU of two occupancies (`metrics.reconstruction.iou_from_occupancy`), 1 where both are empty: two
    empty shapes are alike, which is what an oracle's distance needs."""
    try:
        return iou_from_occupancy(inside, reference)
    except EmptyOccupancyError:
        return 1.0


class OccupancyOracle(LatentOracle):
    """`LatentOracle` in shape space: 1 - the IoU, at fixed points uniform in [-1, 1]^3, of the belief's occupancy
    (SDF < 0) with that of the shape's own code. The latent distance weighs every code direction alike, also the
    many the surface barely moves; this one counts only what changes the shape, as the evaluation's IoU does.
    (The shape's own code, not the ground truth: the decoder's best, which a choice of views can approach.)"""

    name = "oracle-occupancy"

    def __init__(self, true_code: Tensor, observer=None, n_points: int = 16384, seed: int = 0) -> None:
        super().__init__(true_code, observer)
        generator = torch.Generator().manual_seed(seed)
        self.points = torch.rand(n_points, 3, generator=generator) * 2.0 - 1.0  # [P, 3]

    def distance(self, state: PlanState) -> Callable[[FusedCode], float]:
        def occupancy(code: Tensor) -> np.ndarray:  # [P] bool
            return sdf_inside_fn(code_sdf_fn(state.decoder, code))(self.points)

        reference = occupancy(self.true_code)
        return lambda belief: 1.0 - occupancy_iou(occupancy(belief.mu), reference)
