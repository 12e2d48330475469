"""The DeepSDF decoder: f(xyz, z) -> signed distance, as in DeepSDF's official network."""

from __future__ import annotations

from typing import Sequence

import torch
from torch import Tensor, nn
from torch.nn.utils.parametrizations import weight_norm as _weight_norm


class DeepSDFDecoder(nn.Module):
    """MLP on [z, xyz]; the input is concatenated again before the `latent_in` layers.

    DeepSDF's specs (the `deepsdf` config): latent 64, 8 x 512, latent_in (4,), ReLU,
    dropout 0.2 on every hidden layer, weight normalisation, tanh on the output.
    """

    def __init__(
        self,
        latent_size: int = 64,
        hidden_dims: Sequence[int] = (512,) * 8,
        latent_in: Sequence[int] = (4,),
        dropout: float = 0.2,
        weight_norm: bool = True,
        output_tanh: bool = True,
    ) -> None:
        super().__init__()
        self.latent_size = latent_size
        self.latent_in = tuple(latent_in)
        self.dropout = dropout
        self.output_tanh = output_tanh
        in_dim = latent_size + 3
        dims = [in_dim, *hidden_dims, 1]
        if any(not 0 < i < len(dims) - 1 for i in self.latent_in):
            raise ValueError(f"latent_in layers {self.latent_in} must index hidden layers 1..{len(dims) - 2}")
        self.layers = nn.ModuleList()
        for i in range(len(dims) - 1):
            # A layer feeding a latent_in layer outputs fewer features so the concat keeps its width.
            out_dim = dims[i + 1] - in_dim if (i + 1) in self.latent_in else dims[i + 1]
            layer = nn.Linear(dims[i], out_dim)
            is_hidden = i < len(dims) - 2
            self.layers.append(_weight_norm(layer) if (weight_norm and is_hidden) else layer)

    def forward(self, xyz: Tensor, z: Tensor) -> Tensor:
        """SDF at points. xyz [..., 3], z [..., D] broadcastable to xyz's leading dims -> [...]."""
        lead = torch.broadcast_shapes(xyz.shape[:-1], z.shape[:-1])
        inputs = torch.cat([z.expand(*lead, z.shape[-1]), xyz.expand(*lead, 3)], dim=-1)
        x = inputs
        last = len(self.layers) - 1
        for i, layer in enumerate(self.layers):
            if i in self.latent_in:
                x = torch.cat([x, inputs], dim=-1)
            x = layer(x)
            if i < last:
                x = torch.relu(x)
                if self.dropout > 0:
                    x = nn.functional.dropout(x, p=self.dropout, training=self.training)
        if self.output_tanh:
            x = torch.tanh(x)
        return x.squeeze(-1)
