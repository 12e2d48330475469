"""The tiny rendered world and stage-1 folder that the encoder and reconstruction tests build on.

A uniquely named module (several conftests share the name `conftest`): import it directly.
Every render is a random-coloured RGBA image whose alpha is a centred disc.
"""

import json

import numpy as np
import torch
from PIL import Image

from ushape.decoder.artifacts import CodeTable, codes_file, save_codes, save_decoder
from ushape.decoder.network import DeepSDFDecoder


def tiny_decoder_config(latent: int) -> dict:
    return {"_target_": "ushape.decoder.network.DeepSDFDecoder", "latent_size": latent, "hidden_dims": [16, 16],
            "latent_in": [1], "dropout": 0.0}


def write_rgba(path, rng, size):
    """A random-coloured RGBA image whose alpha is a centred disc."""
    yy, xx = np.mgrid[:size, :size]
    disc = (yy - size / 2) ** 2 + (xx - size / 2) ** 2 < (size / 3) ** 2
    rgba = np.concatenate([rng.integers(0, 256, (size, size, 3)), 255 * disc[..., None]], axis=-1)
    Image.fromarray(rgba.astype(np.uint8), "RGBA").save(path)


def write_render_world(root, split_sizes: dict, n_views: int, rng, size: int, K: np.ndarray, world_to_cam: np.ndarray):
    """root/splits/<split>.json with ids <split>_<i>, and per shape n_views renders plus views.npz (K, world_to_cam)."""
    (root / "splits").mkdir(parents=True)
    for split, n in split_sizes.items():
        ids = [f"{split}_{i}" for i in range(n)]
        (root / "splits" / f"{split}.json").write_text(json.dumps(ids))
        for shape_id in ids:
            folder = root / "renders" / shape_id
            folder.mkdir(parents=True)
            for v in range(n_views):
                write_rgba(folder / f"{v:02d}.png", rng, size)
            np.savez(folder / "views.npz", K=K, world_to_cam=world_to_cam)


def write_decoder_folder(folder, split_sizes: dict, latent: int):
    """A stage-1 folder: a tiny random decoder (seed 0) and random codes (std 0.1) for every split."""
    folder.mkdir()
    torch.manual_seed(0)
    config = tiny_decoder_config(latent)
    save_decoder(folder / "decoder.pt", DeepSDFDecoder(**{k: v for k, v in config.items() if k != "_target_"}), config)
    for split, n in split_sizes.items():
        save_codes(folder / codes_file(split), CodeTable([f"{split}_{i}" for i in range(n)], 0.1 * torch.randn(n, latent)))
    return folder
