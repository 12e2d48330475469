"""Fixtures for stage 2: a tiny stage-1 decoder folder and a tiny rendered world."""

import json

import numpy as np
import pytest
import torch
from PIL import Image

from ushape.decoder.artifacts import CodeTable, codes_file, save_codes, save_decoder
from ushape.decoder.network import DeepSDFDecoder

LATENT = 8
DECODER_CONFIG = {
    "_target_": "ushape.decoder.network.DeepSDFDecoder",
    "latent_size": LATENT,
    "hidden_dims": [16, 16],
    "latent_in": [1],
    "dropout": 0.0,
}
SPLIT_SIZES = {"train": 4, "val": 3, "test": 2}
N_VIEWS = 3
IMAGE_SIZE = 24


def write_rgba(path, rng, size=IMAGE_SIZE):
    """A random-coloured RGBA image whose alpha is a centred disc."""
    yy, xx = np.mgrid[:size, :size]
    disc = (yy - size / 2) ** 2 + (xx - size / 2) ** 2 < (size / 3) ** 2
    rgba = np.concatenate([rng.integers(0, 256, (size, size, 3)), 255 * disc[..., None]], axis=-1)
    Image.fromarray(rgba.astype(np.uint8), "RGBA").save(path)


@pytest.fixture
def world(tmp_path):
    """<tmp>/world with splits and N_VIEWS renders (+ views.npz) per shape."""
    root = tmp_path / "world"
    rng = np.random.default_rng(0)
    (root / "splits").mkdir(parents=True)
    for split, n in SPLIT_SIZES.items():
        ids = [f"{split}_{i}" for i in range(n)]
        (root / "splits" / f"{split}.json").write_text(json.dumps(ids))
        for shape_id in ids:
            folder = root / "renders" / shape_id
            folder.mkdir(parents=True)
            for v in range(N_VIEWS):
                write_rgba(folder / f"{v:02d}.png", rng)
            np.savez(folder / "views.npz", K=np.tile(np.eye(3), (N_VIEWS, 1, 1)), world_to_cam=np.tile(np.eye(4), (N_VIEWS, 1, 1)))
    return root


@pytest.fixture
def decoder_dir(tmp_path):
    """A stage-1 folder: a tiny decoder plus random codes for every split of `world`."""
    folder = tmp_path / "decoder"
    folder.mkdir()
    torch.manual_seed(0)
    decoder = DeepSDFDecoder(**{k: v for k, v in DECODER_CONFIG.items() if k != "_target_"})
    save_decoder(folder / "decoder.pt", decoder, DECODER_CONFIG)
    for split, n in SPLIT_SIZES.items():
        save_codes(folder / codes_file(split), CodeTable([f"{split}_{i}" for i in range(n)], 0.1 * torch.randn(n, LATENT)))
    return folder


@pytest.fixture
def tiny_encoder():
    """An ImageEncoder config small enough for CPU tests (random-init ResNet-18)."""
    return {"backbone": {"_target_": "ushape.encoder.backbones.resnet18", "pretrained": False}, "latent_size": LATENT}


@pytest.fixture
def world_spec():
    """The sizes of the `world` and `decoder_dir` fixtures."""
    return {"latent": LATENT, "splits": dict(SPLIT_SIZES), "n_views": N_VIEWS, "image_size": IMAGE_SIZE}
