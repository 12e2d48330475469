"""Stage 2: an image encoder predicting a diagonal Gaussian N(mu, diag(sigma^2)) over the latent code."""

from ushape.encoder.heads import GaussianHead, ImageEncoder
from ushape.encoder.losses import energy_score, gaussian_nll, l2_loss

__all__ = ["GaussianHead", "ImageEncoder", "energy_score", "gaussian_nll", "l2_loss"]
