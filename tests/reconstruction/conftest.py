"""The reconstruction tests' shared run: tiny_run's encoder with an analytic sphere decoder swapped in."""

import pytest
import torch

from ushape.reconstruction.predictor import load_predictor


class SphereDecoder(torch.nn.Module):
    """|x| - (0.5 + 0.1 z_0 (1 + x_0)): a sphere whose +x side depends on the code more than its -x side."""

    latent_size = 8

    def __init__(self):
        super().__init__()
        self.scale = torch.nn.Parameter(torch.tensor(0.1))

    def forward(self, xyz, z):
        return xyz.norm(dim=-1) - (0.5 + self.scale * z[..., 0] * (1 + xyz[..., 0]))


@pytest.fixture(scope="module")
def sphere_predictor(tiny_run):
    predictor = load_predictor(tiny_run["run"])
    object.__setattr__(predictor.model, "decoder", SphereDecoder())
    # A one-step random encoder predicts wild codes; pin it to mu = 0 and one variance for all dims.
    head = predictor.model.encoder.head
    with torch.no_grad():
        for layer in (head.mean, head.logvar):
            layer.weight.zero_()
        head.mean.bias.zero_()
        head.logvar.bias.fill_(-4.6)
    return predictor
