"""Shared test set-up: ushape first (it makes torchvision importable), CPU, small thread pools."""

import os

# One thread per pytest-xdist worker (`make test` runs one worker per core), two without xdist.
os.environ.setdefault("OMP_NUM_THREADS", "1" if os.environ.get("PYTEST_XDIST_WORKER") else "2")

import ushape  # noqa: E402,F401  (must precede torchvision/lightning imports)

# isort: split
import lightning as L  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402
from tiny_render_world import tiny_encoder_config, write_decoder_folder, write_render_world  # noqa: E402

from ushape import atomic  # noqa: E402
from ushape.data.cameras import look_at  # noqa: E402
from ushape.encoder.datamodule import EncoderDataModule  # noqa: E402
from ushape.encoder.module import EncoderModule  # noqa: E402

# OMP_NUM_THREADS=1 make test runs the suite on one thread (the results must not depend on it).
torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))

# The tiny trained run folder (random-init ResNet-18 at 16 px, one SGD step) and its world.
TINY_LATENT = 8
TINY_IMAGE_SIZE = 16
TINY_VIEWS = 3
TINY_RENDER_SIZE = 24  # the world's renders; the encoder sees them at TINY_IMAGE_SIZE
TINY_SPLITS = {"train": 3, "val": 3, "test": 2}


@pytest.fixture(autouse=True)
def _seed():
    torch.manual_seed(0)
    np.random.seed(0)


def make_tiny_run(base) -> dict:
    """{"run": run folder, "world": world root, "decoder_dir": ..., "checkpoint": best.ckpt} under base."""
    world, decoder_dir, run = base / "world", base / "decoder", base / "outputs" / "runs" / "d" / "t_encoder"
    K, w2c = zip(*(look_at(40.0 * v, 25.0, 2.0, 49.13, TINY_RENDER_SIZE) for v in range(TINY_VIEWS)))
    write_render_world(
        world, TINY_SPLITS, TINY_VIEWS, np.random.default_rng(0), TINY_RENDER_SIZE, np.stack(K), np.stack(w2c)
    )
    write_decoder_folder(decoder_dir, TINY_SPLITS, TINY_LATENT)
    encoder = tiny_encoder_config(TINY_LATENT)
    loss = {"_target_": "ushape.encoder.losses.gaussian_nll"}
    model = EncoderModule(str(decoder_dir), encoder, loss, lr=1e-3)
    data = EncoderDataModule(world, decoder_dir, image_size=TINY_IMAGE_SIZE, batch_size=4)
    trainer = L.Trainer(
        accelerator="cpu",
        max_steps=1,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=0,
        default_root_dir=base,
    )
    trainer.fit(model, datamodule=data)
    checkpoint = run / "checkpoints" / "best.ckpt"
    checkpoint.parent.mkdir(parents=True)
    trainer.save_checkpoint(checkpoint)
    (run / ".hydra").mkdir()
    (run / ".hydra" / "config.yaml").write_text(
        f"stage2:\n  data:\n    image_size: {TINY_IMAGE_SIZE}\n    mask_mode: gt_mask\n"
    )
    atomic.write_json(
        run / "run.json",
        {
            "stage": "encoder",
            "world": str(world),
            "decoder_dir": str(decoder_dir),
            "encoder_checkpoint": str(checkpoint),
        },
    )
    return {"root": base, "run": run, "world": world, "decoder_dir": decoder_dir, "checkpoint": checkpoint}


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """A tiny trained run whose decoder is a random DeepSDF network (see make_tiny_run)."""
    return make_tiny_run(tmp_path_factory.mktemp("tiny_run"))
