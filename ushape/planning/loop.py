"""The active-reconstruction loop: start from one view, fuse, look at the uncertainty, pick the next view, repeat.

    candidates = candidate_views(world, shape_id)               # poses on the orbit, or the recorded views
    encode = ViewEncoder(predictor, candidates, min_scale=1.0)  # acquire (render / read), crop, encode
    steps = active_reconstruction(candidates, encode, UncertainSurface(), predictor.decoder, n_views=6)
    steps[k - 1].mu                                             # the fused code after k views

Each step fuses every view taken so far (Bayesian by default, pose-free as in the paper), optionally
refines that Gaussian on every view taken (`observe`: ushape.planning.observers; masks or depth, a
full-covariance posterior), meshes the belief's mean, propagates its latent variance to the mesh's
vertices (linearised) and lets the strategy score every candidate not yet taken; the best is acquired next.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable, Protocol

import numpy as np
import torch
import trimesh
from torch import Tensor

from ushape.data.augment import corrupted_box, corrupted_view, view_seed
from ushape.fusion.rules import FusedCode
from ushape.fusion.strategies import BayesianFusion
from ushape.mesh.extraction import EmptySurfaceError
from ushape.planning.candidates import CandidateViews
from ushape.planning.criteria import vertex_areas, visible_from
from ushape.planning.observers import FusedGaussian
from ushape.propagation.field import code_mesh
from ushape.propagation.linearised import propagate_linearised
from ushape.refinement.views import ObservedView, crop_view

Encode = Callable[[int], tuple[Tensor, Tensor]]  # candidate index -> (mu [D], var [D]) of its acquired image
Fusion = Callable[[Tensor, Tensor], FusedCode]  # (mu [V, D], var [V, D]) -> fused (var [D] or [D, D])


@dataclass(frozen=True)
class Surface:
    """The fused code's mesh with its SDF variance per vertex, and what each candidate would see of it."""

    mesh: trimesh.Trimesh
    variance: np.ndarray  # [V] linearised SDF variance at each vertex
    area: np.ndarray  # [V] the surface each vertex stands for
    visible: np.ndarray  # [C, V] bool: candidate c sees vertex v
    seen: np.ndarray  # [V] bool: a view already taken sees vertex v


def surface_of(
    decoder, fused: FusedCode, candidates: CandidateViews, taken: list[int], resolution: int = 40
) -> Surface | None:
    """The Surface of the fused code's mean (None when its SDF has no zero level set in [-1, 1]^3)."""
    try:
        mesh, _ = code_mesh(decoder, fused.mu, resolution)
    except EmptySurfaceError:
        return None
    vertices = torch.as_tensor(np.asarray(mesh.vertices), dtype=torch.float32)
    _, variance = propagate_linearised(decoder, fused.mu.float(), fused.var.float(), vertices)
    visible = visible_from(mesh, candidates.K, candidates.world_to_cam, candidates.image_hw)
    return Surface(
        mesh,
        variance.double().numpy(),
        vertex_areas(mesh.vertices, mesh.faces),
        visible,
        visible[taken].any(axis=0),
    )


@dataclass
class PlanState:
    """What a strategy may look at when it scores the candidates: the poses, the views taken, the fused code."""

    candidates: CandidateViews
    taken: list[int]
    fused: FusedCode
    decoder: object
    resolution: int
    encode: Encode  # only an oracle looks at a candidate's image before it is taken
    fusion: Fusion
    observes: str = "none"  # what the belief was refined on: none (the fused Gaussian), masks or depth

    @cached_property
    def surface(self) -> Surface | None:
        """The current mesh and its vertex variance, computed when a strategy first asks for it."""
        return surface_of(self.decoder, self.fused, self.candidates, self.taken, self.resolution)


class Strategy(Protocol):
    name: str

    def scores(self, state: PlanState) -> np.ndarray:
        """[C] one score per candidate, higher is better (taken candidates are skipped whatever their score)."""


@dataclass(frozen=True)
class Step:
    """One acquisition: the candidate taken, the belief after it (the fused Gaussian, or its refinement on the
    views taken), and the scores that chose it."""

    view: int
    mu: Tensor  # [D] the belief's mean after this view
    var: Tensor  # [D] fused variance, or [D, D] where the fusion or a refining observer gives a full covariance
    scores: np.ndarray | None = None  # [C] the strategy's scores when this view was chosen (None: the start)
    surface: Surface | None = field(default=None, repr=False)  # the surface those scores were computed on
    seconds: float = math.nan  # wall time of the scoring that chose this view and of the belief after it
    fallback: str | None = None  # why the refined belief fell back to the fused Gaussian (None: it did not)


def active_reconstruction(
    candidates: CandidateViews,
    encode: Encode,
    strategy: Strategy,
    decoder,
    n_views: int,
    start: int = 0,
    fusion: Fusion | None = None,
    resolution: int = 40,
    observe=None,
) -> list[Step]:
    """Acquire up to n_views candidates, starting from `start`, each next one the strategy's best untaken one.

    observe: an observer of ushape.planning.observers (default: the fused Gaussian as it is); a refining one
    reads each view's camera, mask and depth from `encode.observed` (ViewEncoder: cropped as the encoder saw
    it), else from the candidates."""
    if n_views < 1:
        raise ValueError(f"n_views must be >= 1, got {n_views}")
    if not 0 <= start < len(candidates):
        raise ValueError(f"start view {start} is not one of the {len(candidates)} candidates")
    fusion, observe = fusion or BayesianFusion(), observe or FusedGaussian()
    view_of = getattr(encode, "observed", candidates.observed)
    taken, mus, variances, steps = [], [], [], []
    view, scores, surface, scoring = start, None, None, 0.0
    while True:
        began = time.perf_counter()
        mu, var = encode(view)
        taken.append(view)
        mus.append(mu)
        variances.append(var)
        fused = fusion(torch.stack(mus), torch.stack(variances))
        belief, fell_back = observe(decoder, fused, list(taken), view_of)
        seconds = scoring + time.perf_counter() - began
        steps.append(Step(view, belief.mu, belief.var, scores, surface, seconds, fell_back))
        if len(taken) >= min(n_views, len(candidates)):
            return steps
        began = time.perf_counter()
        state = PlanState(candidates, list(taken), belief, decoder, resolution, encode, fusion, observe.name)
        scores = np.asarray(strategy.scores(state), dtype=np.float64)
        if scores.shape != (len(candidates),):
            raise ValueError(f"strategy {strategy.name} gave {scores.shape} scores for {len(candidates)} candidates")
        surface = state.__dict__.get("surface")  # kept only if the strategy computed it
        open_scores = np.where(np.isin(np.arange(len(candidates)), taken), -np.inf, scores)
        view = int(np.argmax(open_scores))  # ties: the lowest index
        scoring = time.perf_counter() - began


class ViewEncoder:
    """Candidate index -> (mu [D], var [D]) of its acquired image as the encoder sees it (cached per candidate).

    The image is cropped to a random area in [min_scale, 1] and composited on the model's background, as the
    corrupted-views protocol does; each candidate's crop is seeded by (seed, shape, candidate), so a view
    looks the same whichever strategy takes it. A recorded candidate gets exactly the evaluation's crop of
    that view.
    """

    def __init__(self, predictor, candidates: CandidateViews, min_scale: float = 1.0, seed: int = 0) -> None:
        if not 0 < min_scale <= 1:
            raise ValueError(f"min_scale must be in (0, 1], got {min_scale}")
        self.predictor, self.candidates, self.min_scale, self.seed = predictor, candidates, min_scale, seed
        self._cache: dict[int, tuple[Tensor, Tensor]] = {}

    def input(self, index: int) -> Tensor:
        """RGB [3, S, S]: the acquired image, cropped and composited as the encoder gets it."""
        p = self.predictor
        return corrupted_view(
            self.candidates.image(index),
            p.image_size,
            self.min_scale,
            view_seed(self.seed, self._name(), index),
            p.mask_mode,
            p.background_value,
        )

    def observed(self, index: int) -> ObservedView:
        """The candidate's camera, mask and depth cut to the very crop `input` took (outside it: unobserved)."""
        view = self.candidates.observed(index)
        height, width = view.image_hw
        box = corrupted_box(height, width, self.min_scale, view_seed(self.seed, self._name(), index))
        return crop_view(view, box, (box[2], box[3]))

    def _name(self) -> str:
        return self.candidates.shape_id if self.candidates.source == "recorded" else f"{self.candidates.shape_id}@orbit"

    def __call__(self, index: int) -> tuple[Tensor, Tensor]:
        if index not in self._cache:
            mu, var = self.predictor.encode(self.input(index)[None])
            self._cache[index] = (mu[0].float(), var[0].float())
        return self._cache[index]
