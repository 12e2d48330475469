"""A latent Gaussian with a full covariance: what is refused and why, its square root, marginals and trace."""

import pytest
import torch

from ushape.decoder.latent_gaussian import covariance_factor, latent_trace, marginal_variance
from ushape.decoder.query import check_latent_gaussian


def correlated_covariance(d: int, seed: int = 0, dtype=torch.float64) -> torch.Tensor:
    """B B^T + 0.01 I with B [D, 2]: variances of order 1 and correlations near +-1 between most dimensions."""
    b = torch.randn(d, 2, generator=torch.Generator().manual_seed(seed), dtype=dtype)
    return b @ b.T + 0.01 * torch.eye(d, dtype=dtype)


@pytest.mark.parametrize(
    "var, message",
    [
        (torch.eye(6)[:, :5], r"must be square \[D, D\]"),
        (torch.eye(5), r"mu \[D\] and var \[D\] \(or a full covariance \[D, D\]\)"),
        (torch.eye(6).masked_fill(torch.eye(6, dtype=torch.bool), float("nan")), "NaN/inf"),
        (torch.eye(6) + torch.triu(torch.ones(6, 6), 1) * 0.5, "not symmetric"),
        (torch.tensor([[1.0, 2.0], [2.0, 1.0]]).kron(torch.eye(3)), "not positive semi-definite"),
        (-torch.eye(6), "not positive semi-definite"),
    ],
)
def test_a_bad_full_covariance_is_refused_with_what_is_wrong(var, message):
    with pytest.raises(ValueError, match=message):
        check_latent_gaussian(torch.zeros(6), var)


def test_a_singular_or_float32_covariance_passes():
    b = torch.randn(6, 2, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    check_latent_gaussian(torch.zeros(6), b @ b.T)  # rank 2: positive semi-definite, not definite
    check_latent_gaussian(torch.zeros(6), torch.zeros(6, 6))  # a point mass
    # A Laplace covariance as a float32 inverse of a Hessian is symmetric and PSD only to rounding.
    j = torch.randn(40, 64, generator=torch.Generator().manual_seed(2))
    hessian = torch.eye(64) + j.T @ j * 100
    covariance = torch.linalg.inv(hessian)
    assert not torch.equal(covariance, covariance.T)
    check_latent_gaussian(torch.zeros(64), covariance)


def test_the_factor_is_a_square_root_for_definite_singular_and_diagonal_covariances():
    definite = correlated_covariance(6)
    b = torch.randn(6, 2, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    for cov in (definite, b @ b.T):
        factor = covariance_factor(cov)
        assert factor.dtype == cov.dtype
        torch.testing.assert_close(factor @ factor.T, cov, rtol=0, atol=1e-12)
    # Exact: the factor of a symmetric definite covariance is its Cholesky factor, the same LAPACK call on the same
    # matrix. Symmetrised first: B B^T's two triangles may round differently, which the factor's own (S + S^T) / 2
    # would then change.
    symmetric = (definite + definite.T) / 2
    torch.testing.assert_close(covariance_factor(symmetric), torch.linalg.cholesky(symmetric), rtol=0, atol=0)
    # a zero variance: no Cholesky, still exact (sqrt is correctly rounded on any CPU)
    var = torch.tensor([0.3, 0.0, 2.0, 1e-8], dtype=torch.float32)
    assert torch.equal(covariance_factor(torch.diag(var)), torch.diag(var.sqrt()))


def test_marginals_and_trace_read_the_diagonal():
    cov = correlated_covariance(5)
    assert torch.equal(marginal_variance(cov), cov.diagonal())
    assert latent_trace(cov) == pytest.approx(float(torch.trace(cov)), rel=1e-15)
    # strong off-diagonals: the sum of all entries is not the trace
    assert latent_trace(cov) != pytest.approx(float(cov.sum()), rel=0.1)
    var = torch.tensor([0.1, 0.2, 0.3])
    assert torch.equal(marginal_variance(var), var) and torch.equal(latent_trace(var), var.sum())
