"""A trained decoder at one latent code: the SDF at many points, in chunks, and as a callable.

The shared building block of every stage downstream (grids, meshes, propagation, depth): one place
that checks a code and its points, folds the code into a DeepSDF network (`fold_code`), and runs the
decoder frozen, in chunks of DEFAULT_CHUNK points, optionally in bf16.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Callable, Iterator

import torch
from torch import Tensor, nn
from torch.nn.utils import parametrize

from ushape.decoder.folded import fold_code
from ushape.decoder.latent_gaussian import check_covariance, is_full_covariance
from ushape.mesh.extraction import DEFAULT_CHUNK

Decoder = Callable[[Tensor, Tensor], Tensor]  # (xyz [..., 3], z [..., D]) -> sdf [...]


def decoder_autocast(device: torch.device | str, enabled: bool) -> torch.autocast:
    """bf16 autocast for a decoder forward on `device` (CPU AMX/AVX-512 or CUDA); a no-op if disabled."""
    device_type = torch.device(device).type
    return torch.autocast(device_type=device_type, dtype=torch.bfloat16, enabled=enabled)


def decoder_device(decoder: nn.Module, default: torch.device | str = "cpu") -> torch.device:
    """Where the decoder's weights live; `default` for a decoder without any (an analytic SDF)."""
    parameter = next(decoder.parameters(), None) if isinstance(decoder, nn.Module) else None
    return torch.device(default) if parameter is None else parameter.device


def decode_points(
    decoder: Decoder,
    z: Tensor,  # [D]
    points: Tensor,  # [P, 3]
    chunk: int = DEFAULT_CHUNK,
    bf16: bool = False,
) -> Tensor:  # [P]
    """SDF f(x, z) at every point for one latent code, in chunks of `chunk` points, without gradients.

    A DeepSDFDecoder runs with the code folded in (`fold_code`): same values, less work. Under bf16 it
    is folded in bf16 (its point stays float32); another decoder runs under bf16 autocast.
    """
    if z.ndim != 1:
        raise ValueError(f"z must be one latent code of shape [D], got {tuple(z.shape)}")
    if not torch.isfinite(z).all():
        raise ValueError("z holds NaN/inf: every SDF decoded from it would be NaN")
    check_code_size(decoder, z.shape[0])
    check_points(points)
    check_chunk(chunk)
    out = torch.empty(points.shape[0], dtype=output_dtype(points, bf16), device=points.device)
    with frozen(decoder), torch.no_grad():
        folded = fold_code(decoder, z, bf16)
        with decoder_autocast(points.device, bf16 and folded is None):
            for start in range(0, points.shape[0], chunk):
                block = points[start : start + chunk]
                out[start : start + block.shape[0]] = decoder(block, z) if folded is None else folded.sdf(block)
    return out


def code_sdf_fn(decoder: nn.Module, code: Tensor, bf16: bool = False) -> Callable[[Tensor], Tensor]:
    """points [P, 3] -> sdf [P] (float32, on the points' device) of the decoder at code [D] (`decode_points`)."""
    if code.ndim != 1:
        raise ValueError(f"code must be one latent vector [D], got {tuple(code.shape)}")
    weights = next(decoder.parameters(), None) if isinstance(decoder, nn.Module) else None
    # Points come in float32 and a decoder may be float64; one without weights takes the code's.
    device, dtype = (code.device, code.dtype) if weights is None else (weights.device, weights.dtype)
    code = code.detach().to(device=device, dtype=dtype)

    def sdf(points: Tensor) -> Tensor:
        return decode_points(decoder, code, points.to(device=device, dtype=dtype), bf16=bf16).float().to(points.device)

    return sdf


def check_latent_gaussian(mu: Tensor, var: Tensor) -> None:
    """Raise a ValueError unless mu, var are one Gaussian over the latent code: mu [D] with var [D] >= 0
    (diagonal) or var [D, D] (a full covariance: symmetric, positive semi-definite, `check_covariance`)."""
    if var.ndim == 2 and var.shape[0] != var.shape[1]:
        raise ValueError(f"a full covariance var must be square [D, D], got {tuple(var.shape)}")
    if mu.ndim != 1 or var.shape not in (mu.shape, mu.shape * 2):
        raise ValueError(
            f"expected one latent Gaussian with mu [D] and var [D] (or a full covariance [D, D]), "
            f"got {tuple(mu.shape)} and {tuple(var.shape)}"
        )
    if not (torch.isfinite(mu).all() and torch.isfinite(var).all()):
        raise ValueError("mu or var holds NaN/inf; the latent Gaussian must be finite")
    if is_full_covariance(var):
        check_covariance(var)
    elif (var < 0).any():
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


def output_dtype(points: Tensor, bf16: bool) -> torch.dtype:
    """SDFs come back in the points' dtype; bf16 runs come back in float32 for the statistics."""
    return torch.float32 if bf16 else points.dtype


@contextmanager
def frozen(decoder: nn.Module) -> Iterator[nn.Module]:
    """Eval mode, parameters not requiring grad, weight-norm weights computed once; restored on exit.

    Without this, dropout would add noise to every SDF sample, a backward pass for the
    latent Jacobian would also build weight gradients, and weight normalisation would
    recompute every layer's weight on every chunk.
    """
    if not isinstance(decoder, nn.Module):
        yield decoder
        return
    modes = [(module, module.training) for module in decoder.modules()]
    grads = [(param, param.requires_grad) for param in decoder.parameters()]
    decoder.eval()
    for param, _ in grads:
        param.requires_grad_(False)
    try:
        with parametrize.cached():
            yield decoder
    finally:
        for module, training in modes:
            module.training = training
        for param, requires_grad in grads:
            param.requires_grad_(requires_grad)
