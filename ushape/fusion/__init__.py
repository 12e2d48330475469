"""Multi-view fusion: V per-view Gaussians over the latent code -> one Gaussian, in latent space."""

from ushape.fusion.incremental import IncrementalFuser
from ushape.fusion.rules import FusedCode, fuse_average, fuse_bayesian, fuse_bayesian_k
from ushape.fusion.shared import fuse_intersection, fuse_shared, fuse_shared_k
from ushape.fusion.strategies import (
    AverageFusion,
    BayesianFusion,
    BayesianKFusion,
    CovarianceIntersectionFusion,
    SharedErrorFusion,
)

__all__ = [
    "AverageFusion",
    "BayesianFusion",
    "BayesianKFusion",
    "CovarianceIntersectionFusion",
    "FusedCode",
    "IncrementalFuser",
    "SharedErrorFusion",
    "fuse_average",
    "fuse_bayesian",
    "fuse_bayesian_k",
    "fuse_intersection",
    "fuse_shared",
    "fuse_shared_k",
]
