"""Validation pictures: a decoded sphere renders, panels and calibration plots build, TensorBoard gets them."""

import lightning as L
import numpy as np
import torch
from lightning.pytorch.loggers import TensorBoardLogger
from torch import nn

from ushape.encoder.datamodule import EncoderDataModule
from ushape.encoder.figures import mesh_panel, render_code
from ushape.encoder.module import EncoderModule


class SphereDecoder(nn.Module):
    """SDF of a sphere whose radius is 0.3 + code[0]."""

    def __init__(self):
        super().__init__()
        self.scale = nn.Parameter(torch.ones(()))

    def forward(self, xyz, z):
        return self.scale * (xyz.norm(dim=-1) - 0.3 - z[..., 0])


def test_render_code_of_a_sphere_and_of_nothing():
    decoder = SphereDecoder()
    rgba = render_code(decoder, torch.tensor([0.2, 0.0]), resolution=24, image_size=32)
    assert rgba.shape == (32, 32, 4)
    covered = (rgba[..., 3] > 0).mean()
    assert 0.05 < covered < 0.9
    assert render_code(decoder, torch.tensor([-5.0, 0.0]), resolution=16, image_size=32) is None


def test_mesh_panel_builds():
    fig = mesh_panel(torch.rand(2, 3, 8, 8), [np.zeros((8, 8, 4), np.uint8), None], [None, None])
    assert len(fig.axes) == 6


def test_validation_writes_figures_to_tensorboard(world, decoder_dir, tiny_encoder, tmp_path):
    model = EncoderModule(
        str(decoder_dir),
        tiny_encoder,
        {"_target_": "ushape.encoder.losses.gaussian_nll"},
        log_meshes=True,
        mesh_views=2,
        mesh_resolution=12,
    )
    logger = TensorBoardLogger(tmp_path, name="tb")
    trainer = L.Trainer(
        accelerator="cpu",
        logger=logger,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=1,
    )
    trainer.validate(model, datamodule=EncoderDataModule(world, decoder_dir, image_size=16, batch_size=4))
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(logger.log_dir)).Reload()
    assert {"val/latent_calibration", "val/meshes"} <= set(events.Tags()["images"])
