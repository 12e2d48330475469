"""The configured decoders: output shapes and the latent_in concatenation width."""

from pathlib import Path

import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

CONF = Path(__file__).resolve().parents[2] / "conf" / "decoder"


@pytest.mark.parametrize("name", ["deepsdf", "small"])
def test_configured_decoder_output_shape(name):
    decoder = instantiate(OmegaConf.load(CONF / f"{name}.yaml")).eval()
    xyz = torch.rand(2, 5, 3)
    z = torch.randn(2, 1, decoder.latent_size)
    assert decoder(xyz, z).shape == (2, 5)
    assert decoder(torch.rand(7, 3), torch.randn(decoder.latent_size)).shape == (7,)


def test_latent_in_layer_sees_full_width_after_concatenation():
    decoder = instantiate(OmegaConf.load(CONF / "deepsdf.yaml"))
    width, inputs = 512, decoder.latent_size + 3
    layer_before, layer_in = decoder.layers[3], decoder.layers[4]
    assert layer_before.out_features == width - inputs
    assert layer_in.in_features == width
    assert decoder.layers[0].in_features == inputs
