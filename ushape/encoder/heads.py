"""The uncertainty-aware image encoder: backbone features -> diagonal Gaussian over the latent code."""

from __future__ import annotations

from typing import Any, Mapping

import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf
from torch import Tensor, nn

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def soft_clamp(x: Tensor, low: float, high: float) -> Tensor:
    """Map R smoothly onto (low, high): identity slope 1 at the midpoint, saturating at the bounds."""
    centre, half = (high + low) / 2, (high - low) / 2
    return centre + half * torch.tanh((x - centre) / half)


class GaussianHead(nn.Module):
    """Features [B, F] -> (mu [B, D], logvar [B, D]) with logvar softly kept in (logvar_min, logvar_max).

    The clamp is a scaled tanh rather than a hard clamp: a hard clamp has zero gradient outside the
    range, so a variance pushed past a bound by one large step (lr 0.1) would stay stuck there. The
    tanh keeps a gradient everywhere, is ~identity in the middle, and stops the NLL's 1/sigma^2 and
    the Energy Score's exp(logvar / 2) samples from overflowing. The raw log-variance starts at the
    midpoint (logvar_min + logvar_max) / 2: -4 by default, sigma ~0.14, near DeepSDF codes' spread.
    """

    def __init__(self, in_dim: int, latent_size: int = 64, logvar_min: float = -12.0, logvar_max: float = 4.0) -> None:
        super().__init__()
        if not logvar_min < logvar_max:
            raise ValueError(f"logvar_min ({logvar_min}) must be below logvar_max ({logvar_max})")
        self.logvar_min, self.logvar_max = float(logvar_min), float(logvar_max)
        self.mean = nn.Linear(in_dim, latent_size)
        self.logvar = nn.Linear(in_dim, latent_size)
        nn.init.zeros_(self.logvar.weight)
        nn.init.constant_(self.logvar.bias, (self.logvar_min + self.logvar_max) / 2)

    def start_at(self, mean: Tensor, var: Tensor) -> None:
        """Start from the Gaussian N(mean [D], diag(var [D])) whatever the image: zero the output weights,
        set the biases (the log-variance through the inverse of the soft clamp, kept inside its bounds)."""
        centre, half = (self.logvar_max + self.logvar_min) / 2, (self.logvar_max - self.logvar_min) / 2
        target = var.clamp_min(1e-12).log().clamp(self.logvar_min + 0.01 * half, self.logvar_max - 0.01 * half)
        with torch.no_grad():
            self.mean.weight.zero_()
            self.mean.bias.copy_(mean)
            self.logvar.weight.zero_()
            self.logvar.bias.copy_(centre + half * torch.atanh((target - centre) / half))

    def forward(self, features: Tensor) -> tuple[Tensor, Tensor]:
        logvar = soft_clamp(self.logvar(features), self.logvar_min, self.logvar_max)
        return self.mean(features), logvar


class ImageEncoder(nn.Module):
    """RGB images in [0, 1], [B, 3, H, W] -> (mu [B, D], logvar [B, D]); ImageNet normalisation inside.

    `backbone` is a Hydra config whose `_target_` is a builder in `ushape.encoder.backbones`
    returning (feature extractor, feature dim).
    """

    def __init__(
        self,
        backbone: Mapping[str, Any],
        latent_size: int = 64,
        logvar_min: float = -12.0,
        logvar_max: float = 4.0,
    ) -> None:
        super().__init__()
        if OmegaConf.is_config(backbone):
            backbone = OmegaConf.to_container(backbone, resolve=True)
        if "_target_" not in backbone:
            raise ValueError("encoder.backbone needs a `_target_`, e.g. ushape.encoder.backbones.efficientnet_lite0")
        self.backbone, feature_dim = instantiate(dict(backbone))
        self.head = GaussianHead(feature_dim, latent_size, logvar_min, logvar_max)
        self.register_buffer("pixel_mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("pixel_std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def forward(self, images: Tensor) -> tuple[Tensor, Tensor]:
        if images.ndim != 4 or images.shape[1] != 3:
            raise ValueError(f"images must be RGB [B, 3, H, W] in [0, 1]; got {tuple(images.shape)}")
        features = self.backbone((images - self.pixel_mean) / self.pixel_std)
        return self.head(features.flatten(1))
