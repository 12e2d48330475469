"""Evaluating a frozen decoder f(xyz, z) at many points in chunks, optionally under bf16 autocast."""

from __future__ import annotations

from typing import Callable, ContextManager

import torch
from torch import Tensor

from ushape.decoder.folded import fold_code
from ushape.decoder.query import decoder_autocast, frozen  # noqa: F401  (frozen: re-exported)
from ushape.mesh.extraction import DEFAULT_CHUNK

Decoder = Callable[[Tensor, Tensor], Tensor]  # (xyz [..., 3], z [..., D]) -> sdf [...]


def autocast(bf16: bool, device: torch.device) -> ContextManager:
    """bf16 autocast on `device` when asked, else nothing (see `decoder_autocast`)."""
    return decoder_autocast(device, bf16)


def check_latent_gaussian(mu: Tensor, var: Tensor) -> None:
    """Raise a ValueError unless mu, var are one diagonal Gaussian over the latent code: [D] each, var >= 0."""
    if mu.ndim != 1 or mu.shape != var.shape:
        raise ValueError(
            f"expected one latent Gaussian with mu [D] and var [D], got {tuple(mu.shape)} and {tuple(var.shape)}"
        )
    if not (torch.isfinite(mu).all() and torch.isfinite(var).all()):
        raise ValueError("mu or var holds NaN/inf; the latent Gaussian must be finite")
    if (var < 0).any():
        raise ValueError("var must be >= 0 (a variance, not a log-variance or a standard deviation)")


def check_code_size(decoder: Decoder, size: int) -> None:
    """Raise a ValueError if the decoder declares a latent size (`latent_size`) other than `size`."""
    expected = getattr(decoder, "latent_size", None)
    if expected is not None and int(expected) != size:
        raise ValueError(
            f"the code has {size} dimensions but the decoder takes {expected}: "
            "was it encoded for another decoder (or another latent basis)?"
        )


def check_points(points: Tensor) -> None:
    """Raise a ValueError unless points is [P, 3]."""
    if points.ndim != 2 or points.shape[-1] != 3:
        raise ValueError(f"points must have shape [P, 3], got {tuple(points.shape)}")


def check_chunk(chunk: int) -> None:
    if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise ValueError(f"chunk (points per decoder pass) must be a positive integer, got {chunk!r}")


def decode_points(
    decoder: Decoder,
    z: Tensor,  # [D]
    points: Tensor,  # [P, 3]
    chunk: int = DEFAULT_CHUNK,
    bf16: bool = False,
) -> Tensor:  # [P]
    """SDF f(x, z) at every point for one latent code, in chunks of `chunk` points, without gradients.

    A DeepSDFDecoder runs with the code folded in (`fold_code`, unless bf16): same values, less work.
    """
    if z.ndim != 1:
        raise ValueError(f"z must be one latent code of shape [D], got {tuple(z.shape)}")
    if not torch.isfinite(z).all():
        raise ValueError("z holds NaN/inf: every SDF decoded from it would be NaN")
    check_code_size(decoder, z.shape[0])
    check_points(points)
    check_chunk(chunk)
    out = torch.empty(points.shape[0], dtype=output_dtype(points, bf16), device=points.device)
    with frozen(decoder), torch.no_grad(), autocast(bf16, points.device):
        folded = None if bf16 else fold_code(decoder, z)
        for start in range(0, points.shape[0], chunk):
            block = points[start : start + chunk]
            out[start : start + block.shape[0]] = decoder(block, z) if folded is None else folded.sdf(block)
    return out


def output_dtype(points: Tensor, bf16: bool) -> torch.dtype:
    """SDFs come back in the points' dtype; bf16 runs come back in float32 for the statistics."""
    return torch.float32 if bf16 else points.dtype
