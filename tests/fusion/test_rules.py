"""Known-answer tests for latent-space fusion rules (their speed is a bench.py row, not a test)."""

import pytest
import torch

from ushape.fusion import (
    AverageFusion,
    BayesianFusion,
    BayesianKFusion,
    fuse_average,
    fuse_bayesian,
    fuse_bayesian_k,
)


def _views(*pairs):
    mu = torch.tensor([[m] for m, _ in pairs], dtype=torch.float64)
    var = torch.tensor([[v] for _, v in pairs], dtype=torch.float64)
    return mu, var


def test_two_unit_gaussians_fuse_to_half_variance():
    fused = fuse_bayesian(*_views((0.0, 1.0), (2.0, 1.0)))
    assert fused.mu.item() == pytest.approx(1.0)
    assert fused.var.item() == pytest.approx(0.5)
    assert fused.kept.tolist() == [0, 1]


def test_unequal_gaussians_weight_by_information():
    fused = fuse_bayesian(*_views((0.0, 1.0), (3.0, 4.0)))
    assert fused.mu.item() == pytest.approx(0.6)
    assert fused.var.item() == pytest.approx(0.8)


def test_one_view_returns_itself_exactly():
    mu, var = torch.randn(1, 64), torch.rand(1, 64) + 0.01
    fused = fuse_bayesian(mu, var)
    assert torch.equal(fused.mu, mu[0]) and torch.equal(fused.var, var[0])
    fused_k = fuse_bayesian_k(mu, var, k=1)
    assert torch.equal(fused_k.mu, mu[0]) and torch.equal(fused_k.var, var[0])


def test_variance_floor_keeps_zero_variance_finite():
    mu, var = _views((1.0, 0.0), (5.0, 1.0))
    fused = fuse_bayesian(mu, var, var_floor=1e-6)
    assert torch.isfinite(fused.mu).all() and fused.var.item() > 0
    assert fused.mu.item() == pytest.approx(1.0, abs=1e-4)


def test_average_returns_variance_of_the_mean_of_independent_views():
    mu, var = _views((0.0, 1.0), (3.0, 4.0))
    fused = fuse_average(mu, var)
    assert fused.mu.item() == pytest.approx(1.5)
    assert fused.var.item() == pytest.approx((1.0 + 4.0) / 4)


def test_average_variance_matches_empirical_spread():
    true_var = torch.tensor([0.5, 1.0, 2.0, 4.0])
    draws = torch.randn(200_000, 4) * true_var.sqrt()
    fused = fuse_average(torch.zeros(4, 1), true_var[:, None])
    assert draws.mean(dim=1).var().item() == pytest.approx(fused.var.item(), rel=0.02)


def test_bayesian_k_keeps_lowest_trace_views():
    mu = torch.arange(5, dtype=torch.float64)[:, None].repeat(1, 3)
    var = torch.tensor([3.0, 0.5, 10.0, 0.25, 1.0], dtype=torch.float64)[:, None].repeat(1, 3)
    fused = fuse_bayesian_k(mu, var, k=2)
    assert fused.kept.tolist() == [1, 3]
    expected = fuse_bayesian(mu[[1, 3]], var[[1, 3]])
    assert torch.allclose(fused.mu, expected.mu) and torch.allclose(fused.var, expected.var)
    # information-weighted: (1/0.5 * 1 + 1/0.25 * 3) / (2 + 4) = 14/6
    assert fused.mu[0].item() == pytest.approx(14 / 6)
    assert fuse_bayesian_k(mu, var, k=1).kept.tolist() == [3]


def test_bayesian_k_ties_prefer_earlier_views():
    var = torch.ones(4, 2)
    assert fuse_bayesian_k(torch.zeros(4, 2), var, k=2).kept.tolist() == [0, 1]


def test_bayesian_k_larger_than_views_warns_and_uses_all():
    mu, var = torch.randn(3, 8), torch.rand(3, 8) + 0.1
    with pytest.warns(UserWarning, match="only 3 views"):
        fused = fuse_bayesian_k(mu, var, k=5)
    full = fuse_bayesian(mu, var)
    assert fused.kept.tolist() == [0, 1, 2]
    assert torch.allclose(fused.mu, full.mu) and torch.allclose(fused.var, full.var)


def test_batched_inputs_match_per_object_fusion():
    mu, var = torch.randn(4, 6, 16), torch.rand(4, 6, 16) + 0.05
    # The views each rule keeps are compared by their traces below: Bayesian-K's 3rd and 4th lowest traces of
    # every object lie > 0.1 % apart, so traces within 1e-5 of each other mean the same views were kept (no
    # near-tie for another batching's rounding to flip).
    traces = var.sum(-1)
    ordered = traces.sort(-1).values
    assert ((ordered[:, 3] - ordered[:, 2]) / ordered[:, 3]).min() > 1e-3
    for fuse in (fuse_average, fuse_bayesian, lambda m, v: fuse_bayesian_k(m, v, 3)):
        batched = fuse(mu, var)
        for b in range(4):
            single = fuse(mu[b], var[b])
            assert torch.allclose(batched.mu[b], single.mu, atol=1e-6)
            assert torch.allclose(batched.var[b], single.var, atol=1e-6)
            # in the order kept; a swap of two views whose traces tie within the tolerance would still pass
            assert torch.allclose(traces[b][batched.kept[b]], traces[b][single.kept], rtol=1e-5, atol=0.0)


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: fuse_bayesian(torch.zeros(0, 4), torch.zeros(0, 4)), "no views"),
        (lambda: fuse_bayesian(torch.zeros(2, 4), torch.ones(2, 5)), r"\(2, 4\).*\(2, 5\)"),
        (lambda: fuse_bayesian(torch.zeros(4), torch.ones(4)), r"\[V, D\]"),
        (lambda: fuse_bayesian_k(torch.zeros(2, 4), torch.ones(2, 4), k=0), "k must be an integer >= 1"),
        (lambda: fuse_bayesian(torch.zeros(2, 4), -torch.ones(2, 4)), "negative"),
        (lambda: fuse_bayesian(torch.zeros(2, 4), torch.ones(2, 4), var_floor=0.0), "var_floor"),
    ],
)
def test_bad_input_raises_clear_errors(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_nan_names_the_view():
    mu, var = torch.zeros(4, 3), torch.ones(4, 3)
    mu[2, 1] = float("nan")
    with pytest.raises(ValueError, match=r"mu .*view\(s\) \[2\]"):
        fuse_bayesian(mu, var)
    var[3, 0] = float("nan")
    with pytest.raises(ValueError, match=r"var .*view\(s\) \[3\]"):
        fuse_average(torch.zeros(4, 3), var)


def test_hydra_callables_wrap_the_rules():
    mu, var = torch.randn(5, 8), torch.rand(5, 8) + 0.1
    assert torch.equal(AverageFusion()(mu, var).mu, fuse_average(mu, var).mu)
    assert torch.equal(BayesianFusion(1e-6)(mu, var).var, fuse_bayesian(mu, var, 1e-6).var)
    rule = BayesianKFusion(k=2)
    assert rule.name == "bayesian-2" and BayesianFusion.name == "bayesian" and AverageFusion.name == "average"
    assert torch.equal(rule(mu, var).kept, fuse_bayesian_k(mu, var, 2).kept)
    with pytest.raises(ValueError, match="k must be"):
        BayesianKFusion(k=0)


def test_hydra_instantiates_the_callables():
    from hydra.utils import instantiate

    rule = instantiate({"_target_": "ushape.fusion.BayesianKFusion", "k": 4, "var_floor": 1e-8})
    assert isinstance(rule, BayesianKFusion) and rule.k == 4


def test_k_accepts_integer_likes_and_rejects_others():
    import numpy as np

    mu, var = torch.randn(4, 3), torch.rand(4, 3) + 0.1
    assert fuse_bayesian_k(mu, var, np.int64(2)).kept.shape == (2,)
    for bad in (1.5, True, "2", -1):
        with pytest.raises(ValueError, match="k must be an integer >= 1"):
            fuse_bayesian_k(mu, var, bad)


def test_integer_views_are_fused_as_floats():
    """Integer codes (say, hand-typed) used to fail raw inside mean(); they are numbers like any other."""
    mu, var = torch.tensor([[1, 2], [3, 6]]), torch.tensor([[1, 1], [1, 1]])
    for fused in (fuse_average(mu, var), fuse_bayesian(mu, var), fuse_bayesian_k(mu, var, k=2)):
        assert fused.mu.dtype == torch.get_default_dtype()
        assert torch.allclose(fused.mu, torch.tensor([2.0, 4.0]))


def test_bayesian_fusion_of_huge_means_stays_finite():
    """At the variance floor 1/var * mu overflows float32 for |mu| ~ 1e30; the fused mean does not."""
    mu = torch.tensor([[1e30, -2e30], [3e30, -2e30]])
    var = torch.full_like(mu, 1e-9)
    for fused in (fuse_bayesian(mu, var), fuse_bayesian_k(mu, var, k=2)):
        assert torch.isfinite(fused.mu).all()
        assert torch.allclose(fused.mu, torch.tensor([2e30, -2e30]), rtol=1e-5)
