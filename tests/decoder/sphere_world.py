"""A tiny world of spheres: exact SDFs, so every stage-1 result has a known answer."""

import json

import numpy as np
import pytest
import trimesh
from fake_world import new_world, write_mesh, write_sdf

SPLITS = {
    "train": {"r30": 0.3, "r40": 0.4, "r50": 0.5, "r60": 0.6},
    "val": {"r45": 0.45},
    "test": {"r35": 0.35},
}


def sphere_samples(radius: float, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """DeepSDF-style samples of a sphere: mostly jittered surface points, some uniform in the cube."""
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    near = directions * radius + rng.normal(scale=0.05, size=(n, 1)) * directions
    uniform = rng.uniform(-1, 1, size=(n // 10, 3))
    xyz = np.concatenate([near, uniform]).astype(np.float32)
    rows = np.concatenate([xyz, (np.linalg.norm(xyz, axis=1) - radius)[:, None]], axis=1).astype(np.float32)
    return rows[rows[:, 3] >= 0], rows[rows[:, 3] < 0]


def write_sphere_world(root, n_samples: int = 8000, seed: int = 0):
    rng = np.random.default_rng(seed)
    world = new_world(root, {split: list(shapes) for split, shapes in SPLITS.items()})
    for shapes in SPLITS.values():
        for shape_id, radius in shapes.items():
            write_sdf(world, shape_id, np.concatenate(sphere_samples(radius, n_samples, rng)))
            write_mesh(world, shape_id, trimesh.creation.icosphere(subdivisions=3, radius=radius))
    return root


@pytest.fixture(scope="session")
def sphere_world(tmp_path_factory):
    return write_sphere_world(tmp_path_factory.mktemp("sphere_world"))


@pytest.fixture
def tiny_decoder_config():
    return {
        "_target_": "ushape.decoder.network.DeepSDFDecoder",
        "latent_size": 8,
        "hidden_dims": [32, 32, 32],
        "latent_in": [2],
        "dropout": 0.0,
        "weight_norm": True,
        "output_tanh": True,
    }


def read_json(path):
    return json.loads(path.read_text())


FAST_TRAINER = {
    "accelerator": "cpu",
    "enable_progress_bar": False,
    "enable_model_summary": False,
    "log_every_n_steps": 1,
}
# fit_decoder's settings for a few fast steps on the sphere world (trainer: FAST_TRAINER with max_epochs).
FAST_FIT = dict(
    module={"latent_size": 8, "val_every_n_epochs": 5},
    data={"samples_per_shape": 64, "shapes_per_batch": 2},
    latent_optim={"iterations": 2, "samples_per_iter": 16},
    checkpoint_every_n_epochs=1,
    logger=False,
)


@pytest.fixture(scope="session")
def fitted_sphere_folder(sphere_world, tmp_path_factory):
    """A finished stage-1 folder for the sphere world (decoder, codes, checkpoints, TensorBoard)."""
    from ushape.decoder.fit import fit_decoder

    decoder = {
        "_target_": "ushape.decoder.network.DeepSDFDecoder",
        "latent_size": 8,
        "hidden_dims": [64, 64, 64],
        "latent_in": [2],
        "dropout": 0.0,
    }
    return fit_decoder(
        sphere_world,
        tmp_path_factory.mktemp("stage1") / "decoder",
        decoder,
        module={
            "latent_size": 8,
            "lr_net": 2e-3,
            "lr_codes": 1e-2,
            "code_reg_warmup_epochs": 10,
            "val_every_n_epochs": 60,
            "val_mesh_resolution": 32,
            "val_chamfer_points": 5000,
        },
        trainer={**FAST_TRAINER, "max_epochs": 120},
        data={"samples_per_shape": 1024, "shapes_per_batch": 4, "val_num_shapes": 2},
        latent_optim={"iterations": 200, "lr_drop_at": 150, "samples_per_iter": 2000},
        checkpoint_every_n_epochs=60,
    )
