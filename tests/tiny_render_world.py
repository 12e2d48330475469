"""The tiny rendered world and stage-1 folder that the encoder and reconstruction tests build on.

A uniquely named module (several conftests share the name `conftest`): import it directly.
Every render is a random-coloured RGBA image whose alpha is a centred disc.
"""

import numpy as np
import torch
from fake_world import new_world, write_views

from ushape.decoder.artifacts import CodeTable, codes_file, save_codes, save_decoder
from ushape.decoder.network import DeepSDFDecoder


def tiny_encoder_config(latent: int) -> dict:
    """An ImageEncoder config small enough for CPU tests: a random-init ResNet-18 and a Gaussian head."""
    return {"backbone": {"_target_": "ushape.encoder.backbones.resnet18", "pretrained": False}, "latent_size": latent}


def tiny_decoder_config(latent: int) -> dict:
    return {
        "_target_": "ushape.decoder.network.DeepSDFDecoder",
        "latent_size": latent,
        "hidden_dims": [16, 16],
        "latent_in": [1],
        "dropout": 0.0,
    }


def random_disc(rng, size):
    """A random-coloured RGBA image [size, size, 4] whose alpha is a centred disc."""
    yy, xx = np.mgrid[:size, :size]
    disc = (yy - size / 2) ** 2 + (xx - size / 2) ** 2 < (size / 3) ** 2
    return np.concatenate([rng.integers(0, 256, (size, size, 3)), 255 * disc[..., None]], axis=-1)


def write_render_world(root, split_sizes: dict, n_views: int, rng, size: int, K: np.ndarray, world_to_cam: np.ndarray):
    """Splits with ids <split>_<i>, and per shape n_views renders plus views.npz (K, world_to_cam)."""
    world = new_world(root, {split: [f"{split}_{i}" for i in range(n)] for split, n in split_sizes.items()})
    for shape_id in world.shape_ids():
        write_views(world, shape_id, [random_disc(rng, size) for _ in range(n_views)], K=K, world_to_cam=world_to_cam)


def write_decoder_folder(folder, split_sizes: dict, latent: int):
    """A stage-1 folder: a tiny random decoder (seed 0) and random codes (std 0.1) for every split."""
    folder.mkdir()
    torch.manual_seed(0)
    config = tiny_decoder_config(latent)
    save_decoder(folder / "decoder.pt", DeepSDFDecoder(**{k: v for k, v in config.items() if k != "_target_"}), config)
    for split, n in split_sizes.items():
        save_codes(
            folder / codes_file(split), CodeTable([f"{split}_{i}" for i in range(n)], 0.1 * torch.randn(n, latent))
        )
    return folder
