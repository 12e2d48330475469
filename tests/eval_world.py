"""A world of ellipsoids, an analytic decoder and a fake encoder: the protocols end to end in seconds.

Shape i is an ellipsoid with semi-axes (a_i, 0.5, 0.5) (not a sphere: the Pix3D metrics normalise
scale away); code z decodes to a = 0.5 + 0.3 tanh(z_0). The fake encoder reads a off the image (the
fraction of object pixels of a disc of radius a/2), so cropping an image really does corrupt its
code, and it reports a larger variance for a smaller visible object.
"""

import json
import math

import analytic_decoder as analytic
import numpy as np
import pytest
import torch
import trimesh
from fake_world import new_world, write_mesh, write_sdf, write_views
from tiny_render_world import tiny_encoder_config

from ushape.data.cameras import look_at
from ushape.data.layout import WorldIndex
from ushape.decoder.artifacts import CodeTable, codes_file, save_codes, save_decoder
from ushape.evaluation.code_metrics import Reconstructor
from ushape.evaluation.encoders import EncoderRun
from ushape.evaluation.protocols import EncoderSpec
from ushape.evaluation.settings import Settings
from ushape.evaluation.views import test_views

RADII = {"test_0": 0.3, "test_1": 0.7}
B = 0.5
N_VIEWS = 8
IMAGE = 32
LATENT = 3


def ellipsoid_sdf(xyz, a):
    return analytic.ellipsoid_sdf(xyz, a, B)


ELLIPSOID_DECODER = {"_target_": "analytic_decoder.EllipsoidDecoder", "latent_size": LATENT, "b": B}


def ellipsoid_decoder() -> analytic.EllipsoidDecoder:
    return analytic.EllipsoidDecoder(latent_size=LATENT, b=B)


def code_for_radius(radius):
    return math.atanh((radius - 0.5) / 0.3)


class FakePredictor:
    """Encodes an image to (mu, var) from how much of it the object covers."""

    def __init__(self, checkpoint, probabilistic=True):
        self.checkpoint, self.temperature, self.sdf_temperature, self.image_size = checkpoint, None, None, IMAGE
        self.mask_mode, self.background_value, self.probabilistic = "gt_mask", 1.0, probabilistic
        self.decoder = ellipsoid_decoder()

    def encode(self, images):
        cover = (images.mean(dim=1) < 0.99).float().mean(dim=(1, 2))  # [V] fraction of object pixels
        radius = 2 * (cover / math.pi).sqrt()  # the disc's radius is a/2 image widths
        mu = torch.zeros(len(images), LATENT)
        mu[:, 0] = torch.atanh(((radius - 0.5) / 0.3).clamp(-0.99, 0.99))
        var = torch.ones(len(images), LATENT)
        if self.probabilistic:
            var = var * (0.05 + (0.3 - cover).clamp(min=0))[:, None]  # a cropped view covers less: less sure
        return mu, var


def _disc(radius, rng):
    yy, xx = (np.mgrid[:IMAGE, :IMAGE] + 0.5) / IMAGE - 0.5
    inside = np.hypot(yy, xx) < radius / 2
    rgb = rng.integers(0, 200, (IMAGE, IMAGE, 3))
    return np.concatenate([rgb, 255 * inside[..., None]], -1)


def build_sphere_world(root):
    rng = np.random.default_rng(0)
    # The same shapes in every split, so a real encoder can be fitted on this world in a test.
    world = new_world(
        root,
        {split: list(RADII) for split in ("train", "val", "test")},
        {"category": "spheres", "n_views": N_VIEWS, "image_size": IMAGE},
    )
    for shape_id, radius in RADII.items():
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
        mesh.apply_scale([radius, B, B])
        write_mesh(world, shape_id, mesh)
        points = rng.normal(size=(600, 3))
        points = points / np.linalg.norm(points, axis=1, keepdims=True) * (1 + rng.normal(0, 0.05, (600, 1)))
        points = points * np.array([radius, B, B])
        sdf = ellipsoid_sdf(torch.from_numpy(points), torch.tensor(radius, dtype=torch.float64)).numpy()
        write_sdf(world, shape_id, np.concatenate([points, sdf[:, None]], 1))
        cameras = [look_at(360 * v / N_VIEWS, 20, 3.0, 40, IMAGE) for v in range(N_VIEWS)]
        write_views(
            world,
            shape_id,
            [_disc(radius, rng) for _ in range(N_VIEWS)],
            K=np.stack([c[0] for c in cameras]),
            world_to_cam=np.stack([c[1] for c in cameras]),
        )
    return WorldIndex.load(root)


@pytest.fixture(scope="session")
def sphere_world(tmp_path_factory):
    return build_sphere_world(tmp_path_factory.mktemp("spheres"))


@pytest.fixture(scope="session")
def sphere_codes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("decoder")
    table = CodeTable(list(RADII), torch.tensor([[code_for_radius(r), 0.0, 0.0] for r in RADII.values()]))
    save_codes(folder / codes_file("test"), table)
    save_codes(folder / codes_file("train"), table)  # the same shapes in every split (see build_sphere_world)
    return folder


def tiny_settings(**overrides):
    """The shared settings of a tiny evaluation (each protocol's own: tiny_protocols)."""
    values = dict(group_size=4, resolution=24, n_points=128, calibration_levels=10)
    return Settings(**{**values, **overrides})


# Each protocol's settings at a size that runs in seconds on the ellipsoid world.
TINY_PROTOCOLS = {
    "uncertainty": dict(sdf_points=200, mc_samples=4),
    "corrupted": dict(scales=(0.4, 0.1), k=2, single_view_scales=(1.0, 0.1)),
    "locality": dict(points=200),
    "depth": dict(size=16),
    "view_calibration": dict(k=2, sdf_points=200),
}


def tiny_protocols(names, **settings):
    """The protocols `names` built from their YAML files at TINY_PROTOCOLS's sizes, `settings[name]` on top."""
    from ushape.evaluation.plugin import load_protocols

    return load_protocols(names, {n: {**TINY_PROTOCOLS.get(n, {}), **settings.get(n, {})} for n in names})


def make_run(world, codes_dir, cache_dir, name, tmp_path, settings):
    checkpoint = tmp_path / f"{name}.ckpt"
    checkpoint.write_bytes(name.encode())
    labels = {"es": "Ours", "nll": "Ours-NLL", "l2": "FroDO*"}
    predictor = FakePredictor(checkpoint, probabilistic=name != "l2")
    spec = EncoderSpec(name, labels[name], predictor.probabilistic)
    reconstructor = Reconstructor(
        predictor.decoder, "spheres", world, settings.resolution, cache_dir, n_points=settings.n_points
    )
    return EncoderRun(spec, predictor, world, reconstructor, codes_dir, test_views(world))


@pytest.fixture(scope="session")
def evaluated_dir(sphere_world, sphere_codes, tmp_path_factory):
    """Every protocol for fake ES, NLL and L2 encoders on the ellipsoid world, written like eval.py does."""
    import warnings

    from ushape.evaluation.report import write_results
    from ushape.evaluation.runner import evaluate_all
    from ushape.evaluation.settings import PAPER_PROTOCOLS
    from ushape.evaluation.showcase import Showcase
    from ushape.fusion.strategies import BayesianKFusion

    tmp = tmp_path_factory.mktemp("evaluation")
    settings = tiny_settings()
    runs = [make_run(sphere_world, sphere_codes, tmp / "cache", name, tmp, settings) for name in ("es", "nll", "l2")]
    setting = (BayesianKFusion(k=2), "bayesian-2", 0.4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        protocols = tiny_protocols(PAPER_PROTOCOLS)
        result = evaluate_all(runs, settings, tmp / "cache", setting, tmp / "out", protocols, showcase=Showcase(1, 4))
    write_results(result, tmp / "out")
    return tmp / "out"


def fit_sphere_run(world, tmp_path, run_name: str = "run", max_epochs: int = 1):
    """A finished run folder, tmp_path/<run_name> (run.json + checkpoint), trained a few steps on the ellipsoid world
    (one batch an epoch; an existing folder resumes from its last.ckpt)."""
    from ushape.encoder.fit import fit_encoder

    decoder_dir = tmp_path / "decoder"
    save_decoder(decoder_dir / "decoder.pt", torch.nn.Module(), ELLIPSOID_DECODER)
    table = CodeTable(list(RADII), torch.tensor([[code_for_radius(r), 0.0, 0.0] for r in RADII.values()]))
    for split in ("train", "val", "test"):
        save_codes(decoder_dir / codes_file(split), table)
    run_dir = tmp_path / run_name
    encoder = tiny_encoder_config(3)
    checkpoint = fit_encoder(
        world.root,
        decoder_dir,
        run_dir,
        encoder=encoder,
        loss={"_target_": "ushape.encoder.losses.gaussian_nll"},
        module={"lr": 0.01, "val_samples": 16},
        data={"image_size": 16, "batch_size": 8},
        trainer={
            "accelerator": "cpu",
            "max_epochs": max_epochs,
            "limit_train_batches": 1,
            "limit_val_batches": 1,
            "num_sanity_val_steps": 0,
            "enable_progress_bar": False,
            "enable_model_summary": False,
        },
        logger=False,
    )
    (run_dir / "run.json").write_text(
        json.dumps(
            {
                "stage": "encoder",
                "world": str(world.root),
                "decoder_dir": str(decoder_dir),
                "encoder_checkpoint": str(checkpoint),
            }
        )
    )
    return run_dir
