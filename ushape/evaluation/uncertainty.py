"""Scores of predicted Gaussians in latent space and, propagated through the decoder, in SDF space.

Conventions (the table captions repeat them):
- NLL always *includes* the Gaussian constant, so it is a true negative log-likelihood: in latent
  space per code (summed over the D dimensions, the training loss plus 0.5 D log 2 pi), in SDF
  space per SDF value (univariate).
- ES in latent space is the multivariate Energy Score (Euclidean norm over D, Monte Carlo); in
  SDF space the closed-form univariate one (equal to the CRPS).
- SDF values, predicted and true, are clamped to the decoder's training clamp distance first: the
  decoder was never asked to be right beyond it (DeepSDF's clamped L1), so errors there are noise.
- Surface / Non-Surface split the SDF points by |true SDF| < 0.01 (the paper's Table S1).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ushape.encoder.latent_metrics import latent_scores
from ushape.encoder.losses import gaussian_nll
from ushape.metrics.scores import energy_score_1d, gaussian_nll_1d

SURFACE_BAND = 0.01
EQUAL_VARIANCE = 1.0
REGIONS = ("all", "surface", "non_surface")
SDF_VAR_FLOOR = 1e-6


def latent_nll(mu: Tensor, var: Tensor, target: Tensor) -> Tensor:
    """Mean over codes of -log N(target; mu, diag(var)) with the constant. mu, var, target [N, D] -> []."""
    return gaussian_nll(mu, var.log(), target) + 0.5 * mu.shape[-1] * math.log(2 * math.pi)


def latent_report(mu: Tensor, var: Tensor, target: Tensor, n_samples: int = 1000, n_levels: int = 20) -> dict:
    """ES, NLL (with its constant), L2 and calibration error of latent Gaussians (mu, var [N, D]) against codes [N, D].

    The same scores stage-2 validation logs (`latent_scores`), so a table and TensorBoard agree;
    only the NLL gains the 0.5 D log(2 pi) constant the tables state.
    """
    generator = torch.Generator().manual_seed(0)
    scores = latent_scores(mu, var.log(), target, n_samples=n_samples, n_levels=n_levels, generator=generator)
    return {
        "es": float(scores["latent_es"]),
        "nll": float(scores["latent_nll"]) + 0.5 * mu.shape[-1] * math.log(2 * math.pi),
        "l2": float(scores["latent_l2"]),
        "calibration_error": float(scores["calibration_error"]),
    }


def region_masks(sdf_true: Tensor, band: float = SURFACE_BAND) -> dict[str, Tensor]:
    """Boolean masks [P] of all points, those with |sdf| < band (surface), and the rest."""
    near = sdf_true.abs() < band
    return {"all": torch.ones_like(near), "surface": near, "non_surface": ~near}


def sdf_region_scores(
    mean: Tensor, var: Tensor, sdf_true: Tensor, band: float = SURFACE_BAND, var_floor: float = SDF_VAR_FLOOR
) -> dict[str, float]:
    """Mean univariate ES and NLL per region of SDF predictions N(mean, var) [P] against sdf_true [P].

    Keys `es_all`, `nll_all`, `es_surface`, ...; a region with no points scores NaN. The variance is
    floored (sigma >= 1e-3): where prediction and truth are both clamped, Monte Carlo returns exactly
    0, and an unfloored NLL there would reward a saturated decoder without bound.
    """
    var = var.clamp(min=var_floor)
    es, nll = energy_score_1d(mean, var, sdf_true), gaussian_nll_1d(mean, var, sdf_true)
    out = {}
    for region, mask in region_masks(sdf_true, band).items():
        count = int(mask.sum())
        out[f"es_{region}"] = float(es[mask].mean()) if count else math.nan
        out[f"nll_{region}"] = float(nll[mask].mean()) if count else math.nan
        out[f"n_{region}"] = count
    return out
