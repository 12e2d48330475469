"""Latent optimisation against a frozen decoder, and meshing a trained decoder's codes."""

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree
from sphere_world import sphere_samples

from ushape.bench.contract import FP32_ROUNDING
from ushape.decoder.artifacts import load_codes, load_decoder
from ushape.decoder.latent_optim import optimise_codes
from ushape.decoder.query import code_sdf_fn
from ushape.mesh.extraction import extract_mesh


def test_recovers_held_out_spheres_from_sample_lists(fitted_sphere_folder):
    decoder = load_decoder(fitted_sphere_folder, frozen=False)
    rng = np.random.default_rng(5)
    shapes = []
    for radius in (0.35, 0.55):
        pos, neg = sphere_samples(radius, 3000, rng)
        rows = torch.from_numpy(np.concatenate([pos, neg]))
        shapes.append((rows[:, :3], rows[:, 3]))
    before = [p.detach().clone() for p in decoder.parameters()]
    codes = optimise_codes(decoder, shapes, iterations=200, lr_drop_at=150, samples_per_iter=2000)
    assert codes.shape == (2, 8)
    for code, radius in zip(codes, (0.35, 0.55)):
        mesh, _ = extract_mesh(code_sdf_fn(decoder, code), resolution=48)
        assert np.linalg.norm(mesh.vertices, axis=1).mean() == pytest.approx(radius, abs=0.03)
    # The decoder stayed frozen and gets its training mode and grad flags back.
    assert all(torch.equal(a, b) for a, b in zip(before, decoder.parameters()))
    assert decoder.training and all(p.requires_grad and p.grad is None for p in decoder.parameters())


def test_passes_of_a_few_shapes_give_the_codes_of_one_pass(fitted_sphere_folder):
    """Split into passes (one shape each, or two) or not, each code gets the gradient of its own samples:
    the same codes up to float rounding (the passes' matrix products round in other batches)."""
    decoder = load_decoder(fitted_sphere_folder)
    rng = np.random.default_rng(6)
    shapes = []
    for radius in (0.3, 0.45, 0.6):
        pos, neg = sphere_samples(radius, 1000, rng)
        rows = torch.from_numpy(np.concatenate([pos, neg]))
        shapes.append((rows[:, :3], rows[:, 3]))
    one = optimise_codes(decoder, shapes, iterations=30, samples_per_iter=200, rows_per_pass=10**6)
    for rows_per_pass in (200, 400, 399):  # 1, 2 and (rounded down) 1 shape a pass
        split = optimise_codes(decoder, shapes, iterations=30, samples_per_iter=200, rows_per_pass=rows_per_pass)
        torch.testing.assert_close(split, one, rtol=1e-4, atol=1e-5)
    assert (one[0] - one[2]).abs().max() > 1e-2  # different spheres, different codes: the check can fail


def test_samples_need_both_signs(fitted_sphere_folder):
    decoder = load_decoder(fitted_sphere_folder)
    xyz = torch.rand(10, 3) + 2.0
    with pytest.raises(ValueError, match="inside"):
        optimise_codes(decoder, [(xyz, xyz.norm(dim=1))], iterations=1)


def test_trained_decoder_mesh_is_the_same_coarse_to_fine(fitted_sphere_folder):
    decoder = load_decoder(fitted_sphere_folder)
    code = load_codes(fitted_sphere_folder / "codes_train.pt").lookup("r40")
    dense, _ = extract_mesh(code_sdf_fn(decoder, code), resolution=96, method="dense")
    fast, stats = extract_mesh(code_sdf_fn(decoder, code), resolution=96, method="coarse_to_fine")
    # The same surface up to float32 rounding, not bit for bit: coarse-to-fine decodes other batches, whose matrix
    # products may round a value differently (~1e-7), and a grid value that close to 0 may change its sign and the
    # few faces around it. A wrong block moves vertices by a grid step (0.02) or leaves them out.
    assert abs(len(fast.faces) - len(dense.faces)) <= 0.005 * len(dense.faces)
    for mesh, other in ((fast, dense), (dense, fast)):
        assert cKDTree(other.vertices).query(mesh.vertices)[0].max() <= FP32_ROUNDING
    assert stats.saving > 5
