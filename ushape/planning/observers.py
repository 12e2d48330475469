"""What the loop believes after each view: the paper's fused Gaussian, or that Gaussian refined on the views.

- none: the views' Gaussians fused (Bayesian, pose-free), as the paper does; a diagonal covariance that
  says nothing about which directions a view constrained.
- masks / depth: the fused Gaussian as the prior, refined on every view taken so far through its
  camera (`ushape.refinement.refine`: Levenberg-Marquardt on the silhouettes, or silhouettes and depth)
  to the full-covariance Laplace posterior. The posterior is what the strategy then plans on and what
  the step's code is scored by.

Each observer is named by its file conf/observer/<name>.yaml (see planning.plugins), which builds its class.
"""

from __future__ import annotations

from typing import Callable, Sequence

from torch import Tensor

from ushape.fusion.rules import FusedCode
from ushape.refinement import MODES, ObservedView, refine, refine_settings

ViewOf = Callable[[int], ObservedView]  # candidate index -> its camera, mask and depth as acquired


class FusedGaussian:
    """The fused Gaussian as it is (the paper's)."""

    name = "none"

    def __call__(self, decoder, fused: FusedCode, taken: Sequence[int], view_of: ViewOf) -> tuple[FusedCode, None]:
        return fused, None


class RefinedPosterior:
    """The fused Gaussian refined on the views taken (mode masks or depth), size rays per image side; a setting
    not given is conf/refine.yaml's."""

    def __init__(
        self,
        mode: str = "masks",
        size: int | None = None,
        iterations: int | None = None,
        sigma_mask: float | None = None,
        sigma_depth: float | None = None,
        information_scale: float | None = None,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"a refined observer's mode must be one of {MODES}, got {mode!r}")
        self.name = mode
        self.settings = refine_settings(mode, size, sigma_mask, sigma_depth, iterations, information_scale)

    @classmethod
    def for_sequence(cls, context, **settings):
        """The sequence's rays per side and Levenberg-Marquardt steps, unless the settings give them."""
        return cls(**{"size": context.size, "iterations": context.iterations, **settings})

    def __call__(
        self, decoder, fused: FusedCode, taken: Sequence[int], view_of: ViewOf
    ) -> tuple[FusedCode, str | None]:
        """(the posterior as a FusedCode with a [D, D] covariance, the refinement's fallback reason or None)."""
        posterior = refine(decoder, fused.mu, fused.var, [view_of(i) for i in taken], self.settings)
        return FusedCode(posterior.mu, posterior.cov, fused.kept), posterior.fallback

    def updated_mean(self, decoder, belief: FusedCode, view: ObservedView) -> Tensor:
        """The mean after one more view, refined from the current belief as the prior (the recursive update the
        loop's full refinement approximates): what the diagnostics call the realised effect of a view."""
        return refine(decoder, belief.mu, belief.var, [view], self.settings).mu
