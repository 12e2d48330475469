"""A tiny trained run folder (random-init ResNet-18 at 16 px, one SGD step) and its world."""


import lightning as L
import numpy as np
import pytest
from tiny_render_world import write_decoder_folder, write_render_world

from ushape import atomic
from ushape.data.cameras import look_at
from ushape.encoder.datamodule import EncoderDataModule
from ushape.encoder.module import EncoderModule

LATENT = 8
IMAGE_SIZE = 16
N_VIEWS = 3
RENDER_SIZE = 24  # the world's renders; the encoder sees them at IMAGE_SIZE
SPLITS = {"train": 3, "val": 3, "test": 2}


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """{"run": run folder, "world": world root, "decoder_dir": ..., "checkpoint": best.ckpt}."""
    base = tmp_path_factory.mktemp("tiny_run")
    world, decoder_dir, run = base / "world", base / "decoder", base / "outputs" / "runs" / "d" / "t_encoder"
    K, w2c = zip(*(look_at(40.0 * v, 25.0, 2.0, 49.13, RENDER_SIZE) for v in range(N_VIEWS)))
    write_render_world(world, SPLITS, N_VIEWS, np.random.default_rng(0), RENDER_SIZE, np.stack(K), np.stack(w2c))
    write_decoder_folder(decoder_dir, SPLITS, LATENT)
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
