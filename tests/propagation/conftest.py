"""Decoders with known answers for propagation tests."""

import pytest
import torch
from torch import nn

from ushape.decoder.network import DeepSDFDecoder


class LinearDecoder(nn.Module):
    """s = w . z + a . x + b: first-order propagation is exact, var_s = sum_d w_d^2 var_d."""

    def __init__(self, latent_size: int, dtype: torch.dtype = torch.float64) -> None:
        super().__init__()
        gen = torch.Generator().manual_seed(11)
        self.w = nn.Parameter(torch.randn(latent_size, generator=gen, dtype=dtype))
        self.a = nn.Parameter(torch.randn(3, generator=gen, dtype=dtype))
        self.b = nn.Parameter(torch.tensor(0.3, dtype=dtype))

    def forward(self, xyz, z):
        return (z * self.w).sum(-1) + (xyz * self.a).sum(-1) + self.b


@pytest.fixture
def linear_decoder():
    return LinearDecoder(latent_size=6)


@pytest.fixture
def small_decoder():
    torch.manual_seed(5)
    return DeepSDFDecoder(latent_size=8, hidden_dims=(32,) * 4, latent_in=(2,), dropout=0.2)
