"""Grids and vertices: layout of the field, and uncertainty values on a decoder with a known answer."""

import pytest
import torch

from ushape.propagation import decode_field, field_uncertainty, grid_points, vertex_uncertainty


def test_grid_points_layout():
    points = grid_points(3)
    assert points.shape == (27, 3)
    assert points[0].tolist() == [-1, -1, -1]
    assert points[1].tolist() == [-1, -1, 0]  # z fastest, x slowest (ij order)
    assert points[9].tolist() == [0, -1, -1]
    assert points[-1].tolist() == [1, 1, 1]
    assert torch.allclose(grid_points(5)[:5, 2], torch.tensor([-1.0, -0.5, 0.0, 0.5, 1.0]))
    with pytest.raises(ValueError, match="resolution"):
        grid_points(1)


@pytest.mark.parametrize("method", ["mc", "linearised"])
def test_field_uncertainty_on_a_linear_decoder(linear_decoder, method):
    mu = torch.linspace(-0.5, 0.5, 6, dtype=torch.float64)
    var = torch.full((6,), 0.05, dtype=torch.float64)
    gen = torch.Generator().manual_seed(0)
    mean, variance = field_uncertainty(linear_decoder, mu, var, 5, method, n_samples=4000, generator=gen)
    assert mean.shape == variance.shape == (5, 5, 5)
    with torch.no_grad():
        exact_var = (linear_decoder.w**2 * var).sum().item()
        # grid index (i, j, k) sits at (-1 + i/2, -1 + j/2, -1 + k/2)
        exact_mean = linear_decoder(torch.tensor([0.5, -1.0, 0.0], dtype=torch.float64), mu).item()
    assert mean[3, 0, 2].item() == pytest.approx(exact_mean, abs=1e-12 if method == "linearised" else 0.05)
    assert variance.mean().item() == pytest.approx(exact_var, rel=1e-12 if method == "linearised" else 0.06)


def test_vertex_uncertainty_is_the_standard_deviation(linear_decoder):
    mu = torch.zeros(6, dtype=torch.float64)
    var = torch.full((6,), 0.1, dtype=torch.float64)
    vertices = torch.rand(10, 3, dtype=torch.float64)
    std = vertex_uncertainty(linear_decoder, mu, var, vertices, method="linearised")
    with torch.no_grad():
        assert torch.allclose(std, (linear_decoder.w**2 * var).sum().sqrt().expand(10))
    with pytest.raises(ValueError, match="unknown propagation method"):
        vertex_uncertainty(linear_decoder, mu, var, vertices, method="unscented")


def test_decode_field_matches_direct_decoding(small_decoder):
    z = torch.randn(8) * 0.1
    field = decode_field(small_decoder, z, 4, chunk=10)
    small_decoder.eval()
    with torch.no_grad():
        direct = small_decoder(torch.tensor([1.0, -1 / 3, 1 / 3]), z)
    assert field.shape == (4, 4, 4)
    assert field[3, 1, 2].item() == pytest.approx(direct.item(), abs=1e-6)


def test_clamped_sdf_errors_apply_factor_floor_and_distance_term_on_a_linear_decoder(linear_decoder):
    from ushape.propagation import SDF_CLAMP, clamped_sdf_errors, clamped_sdf_predictions

    mu, var = torch.zeros(1, 6, dtype=torch.float64), torch.full((1, 6), 0.01, dtype=torch.float64)
    with torch.no_grad():  # points whose mean SDF is -0.05, 0.02 and (beyond the clamp) 0.4
        a = linear_decoder.a
        points = torch.stack([t * a / a.square().sum() for t in (-0.35, -0.28, 0.1)])
        exact_var = float((linear_decoder.w**2 * 0.01).sum())
    truth = torch.tensor([0.0, 0.0, 0.5], dtype=torch.float64)
    error, variance, mean = clamped_sdf_predictions(linear_decoder, mu, var, points, truth)
    assert torch.allclose(mean[0], torch.tensor([-0.05, 0.02, SDF_CLAMP], dtype=torch.float64))
    assert torch.allclose(error[0], torch.tensor([0.05, 0.02, 0.0], dtype=torch.float64))  # both clamped at 0.1
    assert torch.allclose(variance[0], torch.tensor([exact_var, exact_var, 0.0], dtype=torch.float64))
    _, std = clamped_sdf_errors(linear_decoder, mu, var, points, truth, 0.5, 0.01, 0.6)
    expected = (0.5 * variance[0] + 0.01**2 + (0.6 * mean[0]) ** 2).sqrt()  # T var + floor^2 + (b |mean|)^2
    assert torch.allclose(std[0], expected)
    _, plain = clamped_sdf_errors(linear_decoder, mu, var, points, truth)
    assert torch.allclose(plain[0], variance[0].sqrt())  # no calibration given: the propagated std itself
