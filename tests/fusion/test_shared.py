import pytest
import torch

from ushape.fusion import (
    BayesianKFusion,
    CovarianceIntersectionFusion,
    SharedErrorFusion,
    fuse_bayesian,
    fuse_bayesian_k,
    fuse_intersection,
    fuse_shared,
)


def _views(v=4, d=3, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(v, d, generator=g), torch.rand(v, d, generator=g) + 0.1


def test_shared_fusion_is_the_analytic_variance_and_bayesian_mean():
    mu = torch.tensor([[0.0, 2.0], [1.0, 4.0]])
    var = torch.tensor([[1.0, 2.0], [3.0, 2.0]])
    shared = torch.tensor([0.5, 0.25])
    fused = fuse_shared(mu, var, shared, view_scale=2.0)
    # S + c (1/1 + 1/3)^-1 = 0.5 + 2 * 0.75; S + c (1/2 + 1/2)^-1 = 0.25 + 2 * 1
    assert torch.allclose(fused.var, torch.tensor([2.0, 2.25]))
    assert torch.allclose(fused.mu, torch.tensor([0.25, 3.0]))
    assert torch.equal(fused.mu, fuse_bayesian(mu, var).mu)


def test_shared_k_keeps_bayesian_ks_choice_of_views():
    mu, var = _views(v=6, d=4)
    rule = SharedErrorFusion(torch.full((4,), 0.3), 0.5, k=2)
    fused, reference = rule(mu, var), fuse_bayesian_k(mu, var, 2)
    assert rule.name == "shared-2"
    assert torch.equal(fused.kept, reference.kept) and torch.equal(fused.kept, BayesianKFusion(2)(mu, var).kept)
    assert torch.allclose(fused.var, 0.3 + 0.5 * reference.var)


def test_shared_rule_without_a_fit_says_how_to_get_one():
    with pytest.raises(ValueError, match="--fit-temperature"):
        SharedErrorFusion()(*_views())


def test_shared_rule_rejects_a_fit_of_another_latent_size():
    with pytest.raises(ValueError, match="D = 3"):
        SharedErrorFusion().calibrated(torch.ones(5), 1.0)(*_views(d=3))


def test_incremental_shared_equals_the_batch_rule():
    mu, var = _views(v=5, d=3)
    for k in (None, 2):
        rule = SharedErrorFusion(torch.tensor([0.1, 0.2, 0.3]), 0.7, k=k)
        stream = rule.incremental()
        for m, v in zip(mu, var):
            stream.add(m, v)
        batch, streamed = rule(mu, var), stream.result()
        assert torch.allclose(batch.var, streamed.var) and torch.allclose(batch.mu, streamed.mu, atol=1e-6)
        assert torch.equal(batch.kept, streamed.kept)  # traces 2e-2 or more apart: no near-tie to flip


def test_intersection_is_the_harmonic_mean_and_does_not_shrink_for_copies():
    mu, var = _views(v=1, d=3)
    copies = fuse_intersection(mu.expand(4, 3), var.expand(4, 3))
    assert torch.allclose(copies.var, var[0]) and torch.allclose(copies.mu, mu[0])
    pair = CovarianceIntersectionFusion()(torch.zeros(2, 1), torch.tensor([[1.0], [3.0]]))
    assert torch.allclose(pair.var, torch.tensor([1.5]))  # 2 / (1 + 1/3)


def test_batched_shared_fusion():
    g = torch.Generator().manual_seed(1)
    mu, var = torch.randn(3, 4, 2, generator=g), torch.rand(3, 4, 2, generator=g) + 0.1
    fused = fuse_shared(mu, var, torch.tensor([0.2, 0.4]))
    for b in range(3):
        assert torch.allclose(fused.var[b], fuse_shared(mu[b], var[b], torch.tensor([0.2, 0.4])).var)


def test_shared_rule_carries_its_sdf_temperature_and_rejects_a_bad_one():
    rule = SharedErrorFusion(k=2).calibrated(torch.ones(3), 0.5, sdf_temperature=1.8)
    assert rule.sdf_temperature == 1.8 and rule.k == 2
    assert SharedErrorFusion().calibrated(torch.ones(3), 0.5).sdf_temperature is None
    for bad in (0.0, -1.0, float("nan"), "warm"):
        with pytest.raises(ValueError, match="sdf_temperature"):
            SharedErrorFusion(torch.ones(3), 0.5, sdf_temperature=bad)
