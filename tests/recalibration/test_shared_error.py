import pytest
import torch

from ushape.fusion import fuse_shared
from ushape.recalibration.shared_error import SharedError, fit_shared_error, shared_variance


def _draw(n_shapes=3000, n_views=6, seed=0, scale=1.0):
    """Views of shapes with a known shared error S and known per-view noise var: e_v = e_shape + e_view."""
    g = torch.Generator().manual_seed(seed)
    shared = torch.tensor([0.5, 0.1, 0.0, 1.0])
    code = torch.randn(n_shapes, 1, 4, generator=g)
    var = 0.05 + torch.rand(n_shapes, n_views, 4, generator=g)
    e_shape = torch.randn(n_shapes, 1, 4, generator=g) * shared.sqrt()
    e_view = torch.randn(n_shapes, n_views, 4, generator=g) * (scale * var).sqrt()
    mu = code + e_shape + e_view
    return shared, code.expand_as(mu), mu, var


def test_views_with_a_known_shared_error_give_it_back():
    shared, code, mu, var = _draw(scale=0.5)
    groups = torch.arange(mu.shape[0]).repeat_interleave(mu.shape[1])
    fit = fit_shared_error(mu.reshape(-1, 4), var.reshape(-1, 4), code.reshape(-1, 4), groups, "diagonal")
    assert fit.n_shapes == mu.shape[0] and fit.structure == "diagonal"
    assert torch.allclose(fit.shared_var, shared, atol=0.04)
    assert fit.view_scale == pytest.approx(0.5, rel=0.05)


def test_proportional_structure_gives_back_a_shared_error_shaped_like_the_views_variance():
    g = torch.Generator().manual_seed(2)
    n_shapes, n_views, profile = 3000, 6, torch.tensor([0.2, 1.0, 0.5, 2.0])
    var = profile * (0.5 + torch.rand(n_shapes, n_views, 4, generator=g))  # mean over views: profile
    shared = 0.3 * var.reshape(-1, 4).mean(0)  # S = 0.3 mean var: one number to find
    code = torch.randn(n_shapes, 1, 4, generator=g).expand(n_shapes, n_views, 4)
    mu = (
        code
        + torch.randn(n_shapes, 1, 4, generator=g) * shared.sqrt()
        + torch.randn(var.shape, generator=g) * var.sqrt()
    )
    groups = torch.arange(n_shapes).repeat_interleave(n_views)
    fit = fit_shared_error(mu.reshape(-1, 4), var.reshape(-1, 4), code.reshape(-1, 4), groups)
    assert fit.structure == "proportional" and torch.allclose(fit.shared_var, shared, rtol=0.05)
    assert fit.view_scale == pytest.approx(1.0, rel=0.05)
    diagonal = fit_shared_error(mu.reshape(-1, 4), var.reshape(-1, 4), code.reshape(-1, 4), groups, "diagonal")
    assert float(fit.shared_var.sum()) == pytest.approx(float(diagonal.shared_var.sum()), rel=1e-5)  # same trace
    with pytest.raises(ValueError, match="structure"):
        fit_shared_error(mu.reshape(-1, 4), var.reshape(-1, 4), code.reshape(-1, 4), groups, "full")


def test_fused_variance_is_the_analytic_one_and_matches_the_fused_error():
    shared, code, mu, var = _draw(seed=1)
    fused = fuse_shared(mu, var, shared)
    analytic = shared + 1 / (1 / var).sum(dim=1)
    assert torch.allclose(fused.var, analytic)
    # the rule's variance is the fused mean's actual squared error (S never averages away)
    error = (fused.mu - code[:, 0]).square().mean(dim=0)
    assert torch.allclose(error, fused.var.mean(dim=0), rtol=0.1, atol=0.01)


def test_shared_variance_uses_only_cross_view_products():
    # one shape, two views: errors (1, -1) and (1, 3) -> cross product 1 and -3 (floored to 0)
    error = torch.tensor([[1.0, -1.0], [1.0, 3.0]])
    s, n = shared_variance(error, ["a", "a"])
    assert n == 1 and torch.allclose(s.float(), torch.tensor([1.0, 0.0]))


def test_single_views_cannot_tell_the_shared_error_apart():
    with pytest.raises(ValueError, match="two or more views"):
        shared_variance(torch.ones(3, 2), ["a", "b", "c"])


def test_record_round_trip():
    fit = SharedError(torch.tensor([0.25, 0.5]), 0.75, 10)
    back = SharedError.from_record(fit.to_record())
    assert torch.equal(back.shared_var, fit.shared_var) and back.view_scale == 0.75 and back.n_shapes == 10
    assert back.sdf_temperature is None and "sdf_temperature" not in fit.to_record()
    assert back.structure == "diagonal"


def test_record_keeps_the_rules_sdf_temperature_and_reads_old_records_without_it():
    fit = SharedError(torch.tensor([0.25, 0.5]), 0.75, 10, sdf_temperature=1.8)
    assert SharedError.from_record(fit.to_record()).sdf_temperature == 1.8
    old = {"var": [0.25, 0.5], "view_scale": 0.75, "n_shapes": 10}  # written before the rule had one
    assert SharedError.from_record(old).sdf_temperature is None and SharedError.from_record(old).structure == "diagonal"
