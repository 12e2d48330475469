"""The narrow-band field equals the dense one wherever it computes, and costs a fraction of it."""

import pytest
import torch
from analytic_decoder import EllipsoidDecoder

from ushape.mesh.extraction import marching_cubes
from ushape.propagation.field import field_uncertainty, narrow_band_field

N = 49


@pytest.fixture
def gaussian():
    mu = torch.tensor([0.2, -0.1, 0.4])
    var = torch.tensor([0.05, 0.01, 0.02])
    return mu, var


def test_linearised_band_equals_the_dense_field_where_computed(gaussian):
    decoder, (mu, var) = EllipsoidDecoder(), gaussian
    band = narrow_band_field(decoder, mu, var, N, "linearised", coarse_resolution=13)
    mean, variance = field_uncertainty(decoder, mu, var, N, "linearised")
    assert band.evaluations < 0.35 * N**3  # pass 1: the coarse grid and the surface's neighbourhood
    assert band.band_points == int(band.band.sum()) + 17**3 and int(band.band.sum()) < 0.5 * band.evaluations
    torch.testing.assert_close(band.mean[band.band], mean[band.band], rtol=0, atol=1e-6)
    torch.testing.assert_close(band.variance[band.band], variance[band.band], rtol=1e-5, atol=1e-9)
    # Every cell that holds surface was computed, so marching cubes sees the dense mesh. Its vertex count follows
    # the signs alone: no grid value lies within 9e-5 of 0 but four exact zeros (the points of the y and z axes at
    # distance b, 0 in any rounding), so the band's other batches, which may round a value differently, keep it.
    crossing = (mean[:-1, :-1, :-1] < 0) != (mean[1:, 1:, 1:] < 0)
    assert band.band[:-1, :-1, :-1][crossing].all()
    dense_mesh, band_mesh = marching_cubes(mean), marching_cubes(band.mean)
    assert len(band_mesh.vertices) == len(dense_mesh.vertices)
    torch.testing.assert_close(
        torch.as_tensor(band_mesh.vertices), torch.as_tensor(dense_mesh.vertices), rtol=0, atol=1e-5
    )
    # Far from the surface the variance is interpolated from a 17^3 grid: close, not equal.
    far = ~band.band
    relative = (band.variance[far] - variance[far]).abs() / variance[far].clamp_min(1e-12)
    assert far.any() and relative.median() < 0.05


def test_mc_band_variance_uses_the_same_codes_as_the_dense_mc_field(gaussian):
    decoder, (mu, var) = EllipsoidDecoder(), gaussian
    band = narrow_band_field(
        decoder, mu, var, N, "mc", n_samples=8, generator=torch.Generator().manual_seed(3), coarse_resolution=13
    )
    mean, variance = field_uncertainty(
        decoder, mu, var, N, "mc", n_samples=8, generator=torch.Generator().manual_seed(3)
    )
    torch.testing.assert_close(band.variance[band.band], variance[band.band], rtol=1e-5, atol=1e-9)
    assert band.variance[band.band].max() > 1e-4  # the codes differ, so there is a variance to compare


def test_bad_method_and_sample_count_are_refused(gaussian):
    mu, var = gaussian
    with pytest.raises(ValueError, match="unknown propagation method"):
        narrow_band_field(EllipsoidDecoder(), mu, var, N, "unscented")
    with pytest.raises(ValueError, match="n_samples"):
        narrow_band_field(EllipsoidDecoder(), mu, var, N, "mc", n_samples=1)


def test_field_uncertainty_offers_the_narrow_band_beside_the_dense_grid(gaussian):
    mu, var = gaussian
    decoder = EllipsoidDecoder()
    band = narrow_band_field(decoder, mu, var, 33)
    mean, variance = field_uncertainty(decoder, mu, var, 33, region="narrow_band")
    # the same function with the same arguments
    assert torch.equal(mean, band.mean) and torch.equal(variance, band.variance)
    with pytest.raises(ValueError, match="region"):
        field_uncertainty(decoder, mu, var, 33, region="sparse")


def test_surface_cell_corners_are_the_corners_of_sign_changing_cells():
    from ushape.propagation.field import surface_cell_corners

    sdf = torch.ones(5, 5, 5)
    sdf[2, 2, 2] = -1.0  # the 8 cells around the centre point change sign; their corners are the 3^3 block
    corners = surface_cell_corners(sdf)
    expected = torch.zeros(5, 5, 5, dtype=torch.bool)
    expected[1:4, 1:4, 1:4] = True
    assert torch.equal(corners, expected)
    widened = surface_cell_corners(sdf, widen=1)
    assert torch.equal(widened, torch.ones(5, 5, 5, dtype=torch.bool))
    assert not surface_cell_corners(torch.ones(4, 4, 4)).any()
