"""Fixtures for stage 2: a tiny stage-1 decoder folder and a tiny rendered world."""

import numpy as np
import pytest
from eval_world import sphere_world  # noqa: F401  (the ellipsoid world a run folder is trained on)
from tiny_render_world import tiny_encoder_config, write_decoder_folder, write_render_world

LATENT = 8
SPLIT_SIZES = {"train": 4, "val": 3, "test": 2}
N_VIEWS = 3
IMAGE_SIZE = 24


@pytest.fixture
def world(tmp_path):
    """<tmp>/world with splits and N_VIEWS renders (+ views.npz, identity cameras) per shape."""
    root = tmp_path / "world"
    write_render_world(
        root,
        SPLIT_SIZES,
        N_VIEWS,
        np.random.default_rng(0),
        IMAGE_SIZE,
        K=np.tile(np.eye(3), (N_VIEWS, 1, 1)),
        world_to_cam=np.tile(np.eye(4), (N_VIEWS, 1, 1)),
    )
    return root


@pytest.fixture
def decoder_dir(tmp_path):
    """A stage-1 folder: a tiny decoder plus random codes for every split of `world`."""
    return write_decoder_folder(tmp_path / "decoder", SPLIT_SIZES, LATENT)


@pytest.fixture
def tiny_encoder():
    """An ImageEncoder config small enough for CPU tests (random-init ResNet-18)."""
    return tiny_encoder_config(LATENT)


@pytest.fixture
def world_spec():
    """The sizes of the `world` and `decoder_dir` fixtures."""
    return {"latent": LATENT, "splits": dict(SPLIT_SIZES), "n_views": N_VIEWS, "image_size": IMAGE_SIZE}
