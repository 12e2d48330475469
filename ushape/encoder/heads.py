"""The uncertainty-aware image encoder: backbone features -> diagonal Gaussian over the latent code."""

from __future__ import annotations

import zlib
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

    With `hidden` > 0 a hidden ReLU layer (and dropout) comes first: on frozen backbone features a
    linear map is too weak and fine-tuning is not there to make the features linear in the code.
    """

    def __init__(
        self,
        in_dim: int,
        latent_size: int = 64,
        logvar_min: float = -12.0,
        logvar_max: float = 4.0,
        hidden: int = 0,
        dropout: float = 0.0,
    ) -> None:
        super().__init__()
        if not logvar_min < logvar_max:
            raise ValueError(f"logvar_min ({logvar_min}) must be below logvar_max ({logvar_max})")
        if hidden < 0 or not 0 <= dropout < 1:
            raise ValueError(f"hidden must be >= 0 and dropout in [0, 1); got {hidden}, {dropout}")
        self.logvar_min, self.logvar_max = float(logvar_min), float(logvar_max)
        self.trunk = (
            nn.Sequential(nn.Linear(in_dim, hidden), nn.ReLU(), nn.Dropout(dropout)) if hidden else nn.Identity()
        )
        out_dim = hidden or in_dim
        self.mean = nn.Linear(out_dim, latent_size)
        self.logvar = nn.Linear(out_dim, latent_size)
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

    @property
    def latent_size(self) -> int:
        return self.mean.out_features

    def forward(self, features: Tensor) -> tuple[Tensor, Tensor]:
        h = self.trunk(features)
        logvar = soft_clamp(self.logvar(h), self.logvar_min, self.logvar_max)
        return self.mean(h), logvar


def mixture_moments(mu: Tensor, logvar: Tensor) -> tuple[Tensor, Tensor]:
    """The Gaussian with the moments of an equal-weight mixture: [E, B, D] each -> (mu [B, D], logvar [B, D]).

    var = mean_e var_e + mean_e (mu_e - mu)^2: the members' own (aleatoric) variance plus their
    disagreement, which grows where they have not seen anything alike (epistemic).
    """
    mean = mu.mean(0)
    var = logvar.exp().mean(0) + (mu - mean).pow(2).mean(0)
    return mean, var.log()


class GaussianEnsemble(nn.Module):
    """E GaussianHeads on the same features, each trained on its own bootstrap of the training shapes.

    A head fitted to the shapes it memorised reports only the error it made on them; on a new shape
    its variance is too small (measured at quickstart scale: 2-3x). Heads that saw different shapes
    disagree most on unfamiliar ones, and the mixture's variance (`mixture_moments`) adds that
    disagreement. `member_of(shape_ids)` says which members train on which shapes. With `cross_fit`
    each member's variance is fitted on the shapes outside its share instead (`losses.ensemble_loss`),
    which needs keep < 1.
    """

    def __init__(
        self,
        in_dim: int,
        latent_size: int = 64,
        members: int = 5,
        keep: float = 2 / 3,
        cross_fit: bool = False,
        **head,
    ) -> None:
        super().__init__()
        if members < 2 or not 0 < keep <= 1:
            raise ValueError(f"an ensemble needs members >= 2 and keep in (0, 1]; got {members}, {keep}")
        if cross_fit and keep >= 1:
            raise ValueError("cross_fit fits each member's variance on the shapes it skips: keep must be < 1")
        self.keep, self.cross_fit = keep, cross_fit
        self.members = nn.ModuleList(GaussianHead(in_dim, latent_size, **head) for _ in range(members))

    @property
    def latent_size(self) -> int:
        return self.members[0].latent_size

    def start_at(self, mean: Tensor, var: Tensor) -> None:
        for member in self.members:
            member.start_at(mean, var)

    def member_outputs(self, features: Tensor) -> tuple[Tensor, Tensor]:
        """features [B, F] -> every member's (mu [E, B, D], logvar [E, B, D])."""
        outputs = [member(features) for member in self.members]
        return torch.stack([m for m, _ in outputs]), torch.stack([v for _, v in outputs])

    def member_of(self, shape_ids: list[str]) -> Tensor:
        """Bool [E, B]: member e trains on shape b (a fixed ~`keep` share of shapes per member, by hash)."""
        draws = torch.tensor(
            [[zlib.crc32(f"{e}/{s}".encode()) / 2**32 for s in shape_ids] for e in range(len(self.members))]
        )
        return draws < self.keep

    def forward(self, features: Tensor) -> tuple[Tensor, Tensor]:
        return mixture_moments(*self.member_outputs(features))


class ImageEncoder(nn.Module):
    """RGB images in [0, 1], [B, 3, H, W] -> (mu [B, D], logvar [B, D]); ImageNet normalisation inside.

    `backbone` is a Hydra config whose `_target_` is a builder in `ushape.encoder.backbones`
    returning (feature extractor, feature dim). `freeze_backbone` keeps its ImageNet weights and
    batch-norm statistics as they are (only the head trains, and its features can be cached);
    `members` > 1 makes the head a bootstrap ensemble (GaussianEnsemble); `cross_fit` fits its members'
    variances on held-out residuals.
    """

    def __init__(
        self,
        backbone: Mapping[str, Any],
        latent_size: int = 64,
        logvar_min: float = -12.0,
        logvar_max: float = 4.0,
        hidden: int = 0,
        dropout: float = 0.0,
        members: int = 1,
        freeze_backbone: bool = False,
        cross_fit: bool = False,
    ) -> None:
        super().__init__()
        if cross_fit and members < 2:
            raise ValueError("cross_fit needs an ensemble head: set encoder.members >= 2 (e.g. 5)")
        if OmegaConf.is_config(backbone):
            backbone = OmegaConf.to_container(backbone, resolve=True)
        if "_target_" not in backbone:
            raise ValueError("encoder.backbone needs a `_target_`, e.g. ushape.encoder.backbones.efficientnet_lite0")
        self.backbone, self.feature_dim = instantiate(dict(backbone))
        head = {"logvar_min": logvar_min, "logvar_max": logvar_max, "hidden": hidden, "dropout": dropout}
        self.head = (
            GaussianEnsemble(self.feature_dim, latent_size, members, cross_fit=cross_fit, **head)
            if members > 1
            else GaussianHead(self.feature_dim, latent_size, **head)
        )
        self.freeze_backbone = freeze_backbone
        if freeze_backbone:
            self.backbone.requires_grad_(False)
            self.backbone.eval()
            # Frozen features are not scaled for a head (pooled stages differ by orders of magnitude):
            # the head reads them standardised by the training views' statistics (`standardise_with`).
            self.register_buffer("feature_mean", torch.zeros(self.feature_dim))
            self.register_buffer("feature_std", torch.ones(self.feature_dim))
        self.register_buffer("pixel_mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("pixel_std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def train(self, mode: bool = True) -> "ImageEncoder":
        super().train(mode)
        if self.freeze_backbone:
            self.backbone.eval()  # frozen batch-norm statistics: cached features stay valid
        return self

    def features(self, images: Tensor) -> Tensor:
        """images [B, 3, H, W] in [0, 1] -> backbone features [B, F] (what the head reads)."""
        if images.ndim != 4 or images.shape[1] != 3:
            raise ValueError(f"images must be RGB [B, 3, H, W] in [0, 1]; got {tuple(images.shape)}")
        return self.backbone((images - self.pixel_mean) / self.pixel_std).flatten(1)

    def standardise_with(self, features: Tensor) -> None:
        """Set the head's input statistics from training features [N, F] (frozen backbone only)."""
        if not self.freeze_backbone:
            raise ValueError("only a frozen backbone's features are standardised; its statistics would drift otherwise")
        with torch.no_grad():
            self.feature_mean.copy_(features.mean(0))
            self.feature_std.copy_(features.std(0).clamp_min(1e-6))

    def head_input(self, features: Tensor) -> Tensor:
        """Backbone features [B, F] as the head reads them: standardised when the backbone is frozen."""
        return (features - self.feature_mean) / self.feature_std if self.freeze_backbone else features

    def forward(self, images: Tensor) -> tuple[Tensor, Tensor]:
        return self.head(self.head_input(self.features(images)))
