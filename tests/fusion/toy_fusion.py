"""A fusion rule that lives outside the package: what a new rule needs (this module and toy_conf/fusion/toy.yaml)."""

import torch

from ushape.fusion.rules import FusedCode


class FirstView:
    """Keeps the first view's Gaussian of each instance and ignores the others."""

    name = "first-view"

    def __call__(self, mu, var) -> FusedCode:  # mu, var [..., V, D] -> [..., D]
        return FusedCode(mu[..., 0, :], var[..., 0, :], torch.zeros(1, dtype=torch.long))
