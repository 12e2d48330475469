"""A tiny trained run folder (random-init ResNet-18 at 16 px, one SGD step) and its world."""

import json

import lightning as L
import numpy as np
import pytest
import torch
from PIL import Image

from ushape import atomic
from ushape.data.cameras import look_at
from ushape.data.render_dataset import EncoderDataModule
from ushape.decoder.artifacts import CodeTable, codes_file, save_codes, save_decoder
from ushape.decoder.network import DeepSDFDecoder
from ushape.encoder.module import EncoderModule

LATENT = 8
IMAGE_SIZE = 16
N_VIEWS = 3
SPLITS = {"train": 3, "val": 3, "test": 2}
DECODER_CONFIG = {
    "_target_": "ushape.decoder.network.DeepSDFDecoder",
    "latent_size": LATENT,
    "hidden_dims": [16, 16],
    "latent_in": [1],
    "dropout": 0.0,
}


def _write_world(root, rng):
    (root / "splits").mkdir(parents=True)
    K, w2c = zip(*(look_at(40.0 * v, 25.0, 2.0, 49.13, 24) for v in range(N_VIEWS)))
    for split, n in SPLITS.items():
        ids = [f"{split}_{i}" for i in range(n)]
        (root / "splits" / f"{split}.json").write_text(json.dumps(ids))
        for shape_id in ids:
            folder = root / "renders" / shape_id
            folder.mkdir(parents=True)
            for v in range(N_VIEWS):
                yy, xx = np.mgrid[:24, :24]
                disc = (yy - 12) ** 2 + (xx - 12) ** 2 < 64
                rgba = np.concatenate([rng.integers(0, 256, (24, 24, 3)), 255 * disc[..., None]], axis=-1)
                Image.fromarray(rgba.astype(np.uint8), "RGBA").save(folder / f"{v:02d}.png")
            np.savez(folder / "views.npz", K=np.stack(K), world_to_cam=np.stack(w2c))


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """{"run": run folder, "world": world root, "decoder_dir": ..., "checkpoint": best.ckpt}."""
    base = tmp_path_factory.mktemp("tiny_run")
    world, decoder_dir, run = base / "world", base / "decoder", base / "outputs" / "runs" / "d" / "t_encoder"
    rng = np.random.default_rng(0)
    _write_world(world, rng)
    decoder_dir.mkdir()
    torch.manual_seed(0)
    decoder = DeepSDFDecoder(**{k: v for k, v in DECODER_CONFIG.items() if k != "_target_"})
    save_decoder(decoder_dir / "decoder.pt", decoder, DECODER_CONFIG)
    for split, n in SPLITS.items():
        codes = 0.1 * torch.randn(n, LATENT)
        save_codes(decoder_dir / codes_file(split), CodeTable([f"{split}_{i}" for i in range(n)], codes))
    encoder = {"backbone": {"_target_": "ushape.encoder.backbones.resnet18", "pretrained": False}, "latent_size": LATENT}
    loss = {"_target_": "ushape.encoder.losses.gaussian_nll"}
    model = EncoderModule(str(decoder_dir), encoder, loss, lr=1e-3)
    data = EncoderDataModule(world, decoder_dir, image_size=IMAGE_SIZE, batch_size=4)
    trainer = L.Trainer(accelerator="cpu", max_steps=1, logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, limit_val_batches=0,
                        default_root_dir=base)
    trainer.fit(model, datamodule=data)
    checkpoint = run / "checkpoints" / "best.ckpt"
    checkpoint.parent.mkdir(parents=True)
    trainer.save_checkpoint(checkpoint)
    (run / ".hydra").mkdir()
    (run / ".hydra" / "config.yaml").write_text(f"stage2:\n  data:\n    image_size: {IMAGE_SIZE}\n    mask_mode: gt_mask\n")
    atomic.write_json(run / "run.json", {"stage": "encoder", "world": str(world), "decoder_dir": str(decoder_dir),
                                         "encoder_checkpoint": str(checkpoint)})
    return {"root": base, "run": run, "world": world, "decoder_dir": decoder_dir, "checkpoint": checkpoint}
