"""The showcase's per-vertex std is drawn from its own seeded generator: the same pictures whatever the
evaluation drew from torch's global generator before it (which protocols ran, in which order)."""

import numpy as np
import torch
from eval_world import make_run, tiny_settings

from ushape.evaluation.showcase import save_showcase
from ushape.evaluation.views import encode_views


def test_the_showcase_std_depends_on_its_seed_not_on_the_global_generator(sphere_world, sphere_codes, tmp_path):
    settings = tiny_settings()
    run = make_run(sphere_world, sphere_codes, tmp_path / "cache", "es", tmp_path, settings)
    encodings = encode_views(run.predictor, run.world, run.keys, 1.0, settings.seed, tmp_path / "cache")

    def stds(out, global_seed, seed):
        torch.manual_seed(global_seed)
        pngs = save_showcase(run, encodings, out, settings.group_size, 1, settings.resolution, 4, seed=seed)
        assert pngs
        return [np.load(p.with_suffix(".npz"))["std"] for p in pngs]

    first, second, other = stds(tmp_path / "a", 1, 0), stds(tmp_path / "b", 2, 0), stds(tmp_path / "c", 1, 5)
    # One code path, batching and thread count in one process, the same seed: the same draws, bit for bit.
    assert all(np.array_equal(a, b) for a, b in zip(first, second))
    assert not all(np.allclose(a, c) for a, c in zip(first, other))
