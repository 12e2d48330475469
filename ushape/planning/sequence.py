"""One next-best-view sequence as the active protocol and `active.py` run it: the plan's settings, the shared
start view, the candidates, the observer, the fusion rule and each strategy's options.

`ActivePlan` holds what decides a sequence (views to take, candidates, the refinement's rays and steps) and
what chooses which sequences run (strategies, observers, crops, shapes); evaluation's Active protocol is
one, with its settings from conf/protocol/plugins/active.yaml.
"""

from __future__ import annotations

import logging
import zlib
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ushape.planning.candidates import SOURCES, candidate_views
from ushape.planning.loop import active_reconstruction
from ushape.planning.observers import FusedGaussian
from ushape.planning.plugins import SequenceContext, build_observer, build_strategy, observer_names, strategy_names
from ushape.reconstruction.calibrated_fusion import refinement_prior

log = logging.getLogger(__name__)


@dataclass
class ActivePlan:
    """views: views taken per sequence, the start view included; strategies: how each next view is chosen;
    observe: after each view, none (the fused Gaussian) or refine it on every view taken (masks, depth);
    refine_size / refine_iterations: rays per image side and Levenberg-Marquardt steps of that refinement
    (and the information strategies' rays); scales: crops of area [scale, 1]; shapes: the first test shapes
    only (None: all); candidates: orbit (renders of the true shape), recorded (the world's views) or auto;
    azimuths x elevations: the orbit's candidates; strategy_dirs / observer_dirs: more folders of strategy /
    observer YAML files (conf/strategy/ and conf/observer/ are always searched; see planning.plugins)."""

    views: int = 6
    strategies: Sequence[str] = ("uncertainty", "unseen-uncertainty", "farthest", "random", "oracle", "information")
    observe: Sequence[str] = ("none",)
    refine_size: int = 24
    refine_iterations: int = 15
    scales: Sequence[float] = (1.0, 0.1)
    shapes: int | None = None
    candidates: str = "auto"
    azimuths: int = 12
    elevations: int = 2
    strategy_dirs: Sequence[str] = ()
    observer_dirs: Sequence[str] = ()

    def __post_init__(self) -> None:
        self.strategies, self.observe, self.scales = list(self.strategies), list(self.observe), list(self.scales)
        self.strategy_dirs, self.observer_dirs = list(self.strategy_dirs), list(self.observer_dirs)
        known = strategy_names(self.strategy_dirs)
        unknown = [s for s in self.strategies if s not in known]
        if unknown or self.views < 1 or self.candidates not in SOURCES:
            raise ValueError(
                f"active: strategies must be some of {known}, views >= 1 and candidates one of {SOURCES}; "
                f"got {self.strategies}, {self.views}, {self.candidates!r}"
            )
        if not all(0 < float(s) <= 1 for s in self.scales):
            raise ValueError(f"active: scales are crop min scales in (0, 1], got {self.scales}")
        observers = observer_names(self.observer_dirs)
        if not set(self.observe) <= set(observers) or not self.observe:
            raise ValueError(f"active: observe must be some of {observers}, got {self.observe}")
        if self.refine_size < 1 or self.refine_iterations < 1:
            raise ValueError(
                "active: refine_size (rays per image side) and refine_iterations must be >= 1, got "
                f"{self.refine_size} and {self.refine_iterations}"
            )


def method_name(strategy: str, observe: str) -> str:
    """A row's name in Table A: the strategy, and what the belief was refined on after each view."""
    return strategy if observe == FusedGaussian.name else f"{strategy}+{observe}"


def start_view(seed: int, shape_id: str, n_candidates: int) -> int:
    """The first view of every strategy for one shape: drawn from (seed, shape id) alone."""
    return int(np.random.default_rng([seed, zlib.crc32(shape_id.encode())]).integers(n_candidates))


def shape_candidates(world, shape_id: str, plan: ActivePlan):
    """The candidate views of one shape under the plan (see planning.candidates)."""
    return candidate_views(world, shape_id, plan.candidates, plan.azimuths, plan.elevations)


def observer_for(plan: ActivePlan, name: str):
    """The observer `name` with the plan's refinement settings."""
    context = SequenceContext(size=plan.refine_size, iterations=plan.refine_iterations)
    return build_observer(name, context, plan.observer_dirs)


def run_strategy(
    predictor, plan: ActivePlan, seed: int, resolution: int, candidates, encode, name, observer, true_code
):
    """One strategy's steps on one shape (from the shared start view), under one observer."""
    context = SequenceContext(seed, true_code, observer, predictor, plan.refine_size, plan.refine_iterations)
    strategy = build_strategy(name, context, plan.strategy_dirs)
    return active_reconstruction(
        candidates,
        encode,
        strategy,
        predictor.decoder,
        plan.views,
        start_view(seed, candidates.shape_id, len(candidates)),
        fusion=loop_fusion(predictor, observer),
        resolution=resolution,
        observe=observer,
    )


def loop_fusion(predictor, observer):
    """The rule that fuses the views taken: Bayesian (the paper's) for the fused belief; for a refining
    observer, the prior reconstruct.py refines, the run's calibrated `shared` rule where fitted (Bayesian's
    variance shrinks as 1/V while the views' shared error stays, so a refinement from it is held near the
    fused mean: measured, the refined IoU fell when a view was added in 40-60 % of the steps)."""
    if getattr(observer, "name", FusedGaussian.name) == FusedGaussian.name:
        return None
    return refinement_prior(predictor)


def observable(names: Sequence[str], candidates) -> list[str]:
    """The observers that can run on these candidates: refining needs their masks (a world's views.npz without
    masks has none); the others are skipped with a warning."""
    if candidates.observation is not None:
        return list(names)
    skipped = [n for n in names if n != FusedGaussian.name]
    if skipped:
        log.warning(
            "active observe %s skipped for %s: its views have no masks to refine on", skipped, candidates.shape_id
        )
    return [n for n in names if n == FusedGaussian.name]
