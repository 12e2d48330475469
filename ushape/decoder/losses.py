"""Stage-1 losses of DeepSDF's auto-decoder, in SDF space and latent space."""

from __future__ import annotations

import torch
from torch import Tensor


def clamped_l1(pred: Tensor, target: Tensor, clamp: float) -> Tensor:
    """Mean |clamp(pred) - clamp(target)| with both clamped to [-clamp, clamp] (DeepSDF's loss). -> []

    pred, target: [...] SDF values of the same shape. Clamping both keeps the decoder's capacity on
    the band around the surface that marching cubes reads; far away only the sign matters.
    """
    if pred.shape != target.shape:
        raise ValueError(f"pred {tuple(pred.shape)} and target {tuple(target.shape)} must have the same shape")
    if clamp <= 0:
        raise ValueError(f"clamp distance must be positive, got {clamp}")
    return (pred.clamp(-clamp, clamp) - target.clamp(-clamp, clamp)).abs().mean()


def code_regulariser(codes: Tensor, lam: float, epoch: int, warmup_epochs: int) -> Tensor:
    """lam * min(1, epoch / warmup_epochs) * mean over the batch of ||z||_2, as DeepSDF trains. -> []

    codes: [B, D], one row per shape (or per SDF sample - every shape has the same number of samples
    in a batch, so the mean is the same). `epoch` counts from 1 as in DeepSDF. DeepSDF's paper writes
    the prior as ||z||^2 / sigma^2, but its train_deep_sdf.py penalises the (unsquared) L2 norm,
    summed over the batch's SDF samples and divided by their number, i.e. the mean norm per sample;
    this is that code's normalisation. (Its reconstruct.py uses 1e-4 * mean(z^2) instead; see
    `latent_optim`.)
    """
    if codes.ndim != 2:
        raise ValueError(f"codes must be [B, D], got {tuple(codes.shape)}")
    if warmup_epochs < 0:
        raise ValueError(f"warmup_epochs must be >= 0, got {warmup_epochs}")
    ramp = 1.0 if warmup_epochs == 0 else min(1.0, epoch / warmup_epochs)
    return lam * ramp * torch.linalg.vector_norm(codes, dim=1).mean()


def code_prior(codes: Tensor, lam: float) -> Tensor:
    """lam * mean over dims of z^2, per code, the Gaussian prior of DeepSDF's reconstruct.py. [S, D] -> [S]"""
    return lam * codes.pow(2).mean(dim=-1)
