"""A trained decoder and one latent code as an SDF callable over points in the normalised frame."""

from __future__ import annotations

from contextlib import contextmanager
from typing import Callable, Iterator

import torch
from torch import Tensor, nn
from torch.nn.utils import parametrize

from ushape.decoder.folded import fold_code


def decoder_autocast(device: torch.device | str, enabled: bool) -> torch.autocast:
    """bf16 autocast for a decoder forward on `device` (CPU AMX/AVX-512 or CUDA); a no-op if disabled."""
    device_type = torch.device(device).type
    return torch.autocast(device_type=device_type, dtype=torch.bfloat16, enabled=enabled)


def decoder_device(decoder: nn.Module, default: torch.device | str = "cpu") -> torch.device:
    """Where the decoder's weights live; `default` for a decoder without any (an analytic SDF)."""
    parameter = next(decoder.parameters(), None)
    return torch.device(default) if parameter is None else parameter.device


def code_sdf_fn(decoder: nn.Module, code: Tensor, bf16: bool = False) -> Callable[[Tensor], Tensor]:
    """points [P, 3] -> sdf [P] (float32, on the points' device) of the decoder at code [D].

    A DeepSDFDecoder in eval mode is evaluated with the code folded in (`fold_code`) unless bf16 is
    asked for; the weights are read when this is called, so call it after the decoder is trained.
    """
    if code.ndim != 1:
        raise ValueError(f"code must be one latent vector [D], got {tuple(code.shape)}")
    device = decoder_device(decoder, code.device)
    code = code.detach().to(device)
    folded = None if bf16 else fold_code(decoder, code)
    if folded is not None:
        dtype = decoder.layers[0].bias.dtype

        def folded_sdf(points: Tensor) -> Tensor:
            with torch.no_grad():
                values = folded.sdf(points.to(device=device, dtype=dtype))
            return values.float().to(points.device)

        return folded_sdf

    def sdf(points: Tensor) -> Tensor:
        with torch.no_grad(), decoder_autocast(device, bf16):
            values = decoder(points.to(device), code)
        return values.float().to(points.device)

    return sdf


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
