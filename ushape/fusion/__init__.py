"""Multi-view fusion: V per-view Gaussians over the latent code -> one Gaussian, in latent space."""

from ushape.fusion.incremental import IncrementalFuser
from ushape.fusion.rules import FusedCode, fuse_average, fuse_bayesian, fuse_bayesian_k
from ushape.fusion.strategies import AverageFusion, BayesianFusion, BayesianKFusion

__all__ = [
    "AverageFusion",
    "BayesianFusion",
    "BayesianKFusion",
    "FusedCode",
    "IncrementalFuser",
    "fuse_average",
    "fuse_bayesian",
    "fuse_bayesian_k",
]
