"""The streaming fuser must agree with the batch rules on every prefix of the views."""

import pytest
import torch

from ushape.fusion import IncrementalFuser, fuse_average, fuse_bayesian, fuse_bayesian_k


@pytest.mark.parametrize("rule, k", [("average", None), ("bayesian", None), ("bayesian_k", 3)])
def test_incremental_matches_batch_on_every_prefix(rule, k):
    gen = torch.Generator().manual_seed(3)
    mu = torch.randn(9, 32, generator=gen, dtype=torch.float64)
    var = torch.rand(9, 32, generator=gen, dtype=torch.float64) * 2 + 0.01
    fuser = IncrementalFuser(rule, k=k)
    for n in range(1, 10):
        fuser.add(mu[n - 1], var[n - 1])
        got = fuser.result()
        if rule == "average":
            want = fuse_average(mu[:n], var[:n])
        elif rule == "bayesian":
            want = fuse_bayesian(mu[:n], var[:n])
        else:
            with pytest.warns(UserWarning) if n < k else _no_warning():
                want = fuse_bayesian_k(mu[:n], var[:n], k)
        assert torch.allclose(got.mu, want.mu, rtol=1e-12, atol=1e-12)
        assert torch.allclose(got.var, want.var, rtol=1e-12, atol=1e-12)
        assert got.kept.tolist() == want.kept.tolist()  # traces 0.1 or more apart: no near-tie to flip


def test_incremental_bayesian_k_evicts_the_worst_view():
    fuser = IncrementalFuser("bayesian_k", k=2)
    for scale in (5.0, 1.0, 3.0, 0.5):
        fuser.add(torch.zeros(4), torch.full((4,), scale))
    assert fuser.result().kept.tolist() == [1, 3]


def test_incremental_single_view_is_exact():
    mu, var = torch.randn(16), torch.rand(16) + 0.1
    fuser = IncrementalFuser("bayesian")
    fuser.add(mu, var)
    assert torch.equal(fuser.result().mu, mu) and torch.equal(fuser.result().var, var)


def test_incremental_bad_input():
    with pytest.raises(ValueError, match="unknown fusion rule"):
        IncrementalFuser("median")
    with pytest.raises(ValueError, match="needs an integer k"):
        IncrementalFuser("bayesian_k")
    fuser = IncrementalFuser("bayesian")
    with pytest.raises(ValueError, match="no views added"):
        fuser.result()
    fuser.add(torch.zeros(4), torch.ones(4))
    with pytest.raises(ValueError, match="latent size 5"):
        fuser.add(torch.zeros(5), torch.ones(5))
    with pytest.raises(ValueError, match=r"view 1 .*NaN"):
        fuser.add(torch.tensor([0.0, float("nan"), 0.0, 0.0]), torch.ones(4))
    with pytest.raises(ValueError, match=r"shape \[D\]"):
        fuser.add(torch.zeros(2, 4), torch.ones(2, 4))


class _no_warning:
    def __enter__(self):
        import warnings

        self._ctx = warnings.catch_warnings()
        self._ctx.__enter__()
        warnings.simplefilter("error")

    def __exit__(self, *exc):
        return self._ctx.__exit__(*exc)
