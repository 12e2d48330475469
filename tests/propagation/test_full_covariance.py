"""Propagation of a latent Gaussian with a full covariance [D, D]: exact answers, Monte Carlo, the diagonal case.

The known answer: a decoder linear in z, s = a(x) . z + b(x), has SDF variance a(x)^T Sigma a(x)
exactly. Sigma = B B^T + 0.01 I (B [D, 2]) couples the dimensions strongly, so reading only its
diagonal gets that variance wrong by far more than any tolerance below.
"""

import pytest
import torch
from torch import nn

from ushape.decoder.query import frozen
from ushape.propagation import (
    field_uncertainty,
    latent_variance,
    narrow_band_field,
    propagate_linearised,
    propagate_mc,
    propagate_to_sdf,
    vertex_uncertainty,
)
from ushape.propagation.linearised import latent_jacobian
from ushape.propagation.monte_carlo import sample_codes


class FeatureLinearDecoder(nn.Module):
    """s = a(x) . z + b(x) with a(x) = phi(x) W: linear in the code, a different direction at every point."""

    def __init__(self, latent_size: int, dtype: torch.dtype = torch.float64) -> None:
        super().__init__()
        gen = torch.Generator().manual_seed(7)
        self.latent_size = latent_size
        self.w = nn.Parameter(torch.randn(6, latent_size, generator=gen, dtype=dtype))

    def features(self, xyz):  # [..., 3] -> [..., 6]
        x, y, z = xyz.unbind(-1)
        return torch.stack([torch.ones_like(x), x, y, z, x * y, torch.sin(3 * z)], -1)

    def slope(self, xyz):  # a(x) [..., D]
        return self.features(xyz) @ self.w

    def forward(self, xyz, code):
        return (self.slope(xyz) * code).sum(-1) + xyz.norm(dim=-1) - 0.5


def correlated(d: int, seed: int = 0, dtype=torch.float64) -> torch.Tensor:
    b = torch.randn(d, 2, generator=torch.Generator().manual_seed(seed), dtype=dtype)
    return b @ b.T + 0.01 * torch.eye(d, dtype=dtype)


def points(n: int, dtype=torch.float64) -> torch.Tensor:
    return torch.rand(n, 3, generator=torch.Generator().manual_seed(2), dtype=dtype) * 2 - 1


def exact_variance(decoder, xyz, cov):
    with torch.no_grad():
        a = decoder.slope(xyz)
    return ((a @ cov) * a).sum(-1)


def test_linearised_is_exact_for_a_decoder_linear_in_z_and_the_diagonal_alone_is_not():
    decoder, cov, xyz = FeatureLinearDecoder(6), correlated(6), points(50)
    mu = torch.linspace(-0.3, 0.3, 6, dtype=torch.float64)
    mean, variance = propagate_linearised(decoder, mu, cov, xyz)
    exact = exact_variance(decoder, xyz, cov)
    with torch.no_grad():
        torch.testing.assert_close(mean, decoder(xyz, mu), rtol=0, atol=1e-12)
    torch.testing.assert_close(variance, exact, rtol=1e-10, atol=0)
    # The test has teeth: a diagonal-only implementation would be off by more than 10% at most points.
    _, diagonal_only = propagate_linearised(decoder, mu, cov.diagonal(), xyz)
    assert ((diagonal_only / exact - 1).abs() > 0.1).float().mean() > 0.8


def test_monte_carlo_with_a_full_covariance_converges_to_the_exact_variance():
    decoder, cov, xyz = FeatureLinearDecoder(6), correlated(6), points(20)
    mu = torch.zeros(6, dtype=torch.float64)
    m = 20000
    mean, variance = propagate_mc(decoder, mu, cov, xyz, n_samples=m, generator=torch.Generator().manual_seed(3))
    exact = exact_variance(decoder, xyz, cov)
    # A sample variance from M draws has relative std sqrt(2 / M) = 1 %; 5 % is 5 of them.
    assert ((variance / exact - 1).abs() < 0.05).all()
    with torch.no_grad():
        assert ((mean - decoder(xyz, mu)).abs() < 5 * (exact / m).sqrt()).all()


def test_sampled_codes_have_the_covariance_even_when_it_is_singular():
    mu = torch.tensor([0.5, -1.0, 0.0, 2.0], dtype=torch.float64)
    b = torch.randn(4, 2, generator=torch.Generator().manual_seed(4), dtype=torch.float64)
    for cov in (correlated(4), b @ b.T):  # definite, and rank 2
        codes = sample_codes(mu, cov, 40000, torch.Generator().manual_seed(5))
        assert codes.shape == (40000, 4)
        torch.testing.assert_close(codes.mean(0), mu, rtol=0, atol=0.05)
        torch.testing.assert_close(torch.cov(codes.T), cov, rtol=0, atol=0.05 * float(cov.abs().max()))
    # rank 2: every code lies in the span of B
    residual = (codes - mu) - (codes - mu) @ torch.linalg.pinv(b).T @ b.T
    assert residual.abs().max() < 1e-6  # a near-zero Cholesky pivot leaves sqrt(eps)-sized noise, no more


def test_latent_variance_of_a_deepsdf_decoder_is_j_sigma_j_for_a_64_dimensional_code():
    """The folded fast path's Jacobian (no autograd) through the full covariance, against autograd's J Sigma J^T."""
    from ushape.decoder.network import DeepSDFDecoder

    torch.manual_seed(5)
    decoder = DeepSDFDecoder(latent_size=64, hidden_dims=(128,) * 4, latent_in=(2,)).eval()
    mu = torch.randn(64) * 0.1
    cov = correlated(64, seed=1).float() * 0.01
    xyz = points(300, torch.float32)
    _, variance = propagate_linearised(decoder, mu, cov, xyz, chunk=128)
    with frozen(decoder):
        _, jacobian = latent_jacobian(decoder, mu, xyz)
    expected = ((jacobian.double() @ cov.double()) * jacobian.double()).sum(-1)
    torch.testing.assert_close(variance.double(), expected, rtol=1e-4, atol=1e-12)


def test_latent_variance_keeps_its_accuracy_for_a_posterior_narrow_along_the_jacobian():
    """float32: the posterior shrinks 64 of 256 directions 10^4-fold and the Jacobians lie mostly in them."""
    gen = torch.Generator().manual_seed(8)
    q, _ = torch.linalg.qr(torch.randn(256, 256, generator=gen, dtype=torch.float64))
    shrink = torch.ones(256, dtype=torch.float64)
    shrink[:64] = 1e-4
    cov = (q * shrink) @ q.T
    cov = (cov + cov.T) / 2
    j = torch.randn(512, 64, generator=gen, dtype=torch.float64) @ q[:, :64].T
    j = j + 1e-3 * torch.randn(512, 256, generator=gen, dtype=torch.float64)
    exact = ((j @ cov) * j).sum(-1)
    got = latent_variance(j.float(), cov.float()).double()
    assert ((got / exact - 1).abs() < 1e-4).all()


def test_a_diagonal_full_covariance_gives_the_diagonal_results(small_decoder):
    gen = torch.Generator().manual_seed(1)
    mu = torch.randn(8, generator=gen) * 0.3
    var = (torch.rand(8, generator=gen) + 0.5) * 0.01
    cov = torch.diag(var)
    xyz = points(200, torch.float32)
    lin_d, lin_f = (propagate_linearised(small_decoder, mu, v, xyz) for v in (var, cov))
    assert torch.equal(lin_d[0], lin_f[0])  # the mean f(x, mu) never reads the variance: one computation
    torch.testing.assert_close(lin_f[1], lin_d[1], rtol=1e-6, atol=0)
    mc_d, mc_f = (propagate_mc(small_decoder, mu, v, xyz, 6, torch.Generator().manual_seed(2)) for v in (var, cov))
    # The same codes, bit for bit: eps @ diag(sqrt(var)) adds only exact zeros to eps * sqrt(var) (any order, any FMA).
    assert torch.equal(mc_d[0], mc_f[0]) and torch.equal(mc_d[1], mc_f[1])
    for method in ("mc", "linearised"):
        std_d, std_f = (
            vertex_uncertainty(small_decoder, mu, v, xyz, method, 5, torch.Generator().manual_seed(3))
            for v in (var, cov)
        )
        torch.testing.assert_close(std_f, std_d, rtol=1e-6, atol=0)
        sdf_d, sdf_f = (propagate_to_sdf(small_decoder, mu, v, xyz, method, 5, seed=4) for v in (var, cov))
        torch.testing.assert_close(sdf_f, sdf_d, rtol=1e-6, atol=0)
        band_d, band_f = (
            narrow_band_field(small_decoder, mu, v, 12, method, 4, torch.Generator().manual_seed(5)) for v in (var, cov)
        )
        assert torch.equal(band_d.band, band_f.band)  # the band comes from the mean's pass, which ignores var
        torch.testing.assert_close(band_f.variance, band_d.variance, rtol=1e-6, atol=0)


def test_the_field_grid_takes_a_full_covariance():
    decoder, cov = FeatureLinearDecoder(6, torch.float32), correlated(6).float()
    mu = torch.zeros(6)
    mean, variance = field_uncertainty(decoder, mu, cov, 9, "linearised")
    grid = torch.stack(torch.meshgrid(*(torch.linspace(-1, 1, 9),) * 3, indexing="ij"), -1).reshape(-1, 3)
    torch.testing.assert_close(variance.reshape(-1), exact_variance(decoder, grid, cov), rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="not positive semi-definite"):
        field_uncertainty(decoder, mu, cov - 2 * torch.eye(6) * float(cov.diagonal().max()), 9, "linearised")
