"""Univariate Gaussian scores against independent implementations and Monte Carlo."""

import math

import numpy as np
import pytest
import scoringrules
import torch

from ushape.metrics.scores import energy_score_1d, gaussian_nll_1d


def test_nll_known_values():
    mu, var, x = torch.tensor([0.0, 1.0]), torch.tensor([1.0, 4.0]), torch.tensor([0.0, 3.0])
    expected = [0.5 * math.log(2 * math.pi), 0.5 * (math.log(2 * math.pi) + math.log(4.0) + 1.0)]
    assert gaussian_nll_1d(mu, var, x).tolist() == pytest.approx(expected)


def test_nll_matches_torch_distributions():
    mu, var, x = torch.randn(50), torch.rand(50) + 0.01, torch.randn(50)
    reference = -torch.distributions.Normal(mu, var.sqrt()).log_prob(x)
    assert torch.allclose(gaussian_nll_1d(mu, var, x), reference, atol=1e-5)


def test_energy_score_matches_scoringrules_crps():
    gen = torch.Generator().manual_seed(0)
    mu = torch.randn(200, generator=gen, dtype=torch.float64)
    var = torch.rand(200, generator=gen, dtype=torch.float64) * 3 + 1e-3
    x = torch.randn(200, generator=gen, dtype=torch.float64) * 2
    reference = scoringrules.crps_normal(x.numpy(), mu.numpy(), var.sqrt().numpy())
    assert np.allclose(energy_score_1d(mu, var, x).numpy(), reference, rtol=1e-10, atol=1e-12)


def test_energy_score_matches_monte_carlo():
    gen = torch.Generator().manual_seed(1)
    mu, var, x = torch.tensor(0.3, dtype=torch.float64), torch.tensor(0.25, dtype=torch.float64), torch.tensor(1.1)
    draws = mu + var.sqrt() * torch.randn(2, 400_000, generator=gen, dtype=torch.float64)
    monte_carlo = (draws[0] - x).abs().mean() - 0.5 * (draws[0] - draws[1]).abs().mean()
    assert energy_score_1d(mu, var, x).item() == pytest.approx(monte_carlo.item(), rel=0.01)


def test_energy_score_at_the_mean_is_known():
    # z = 0: sigma (2 phi(0) - 1/sqrt(pi)) = sigma (sqrt(2) - 1)/sqrt(pi)
    es = energy_score_1d(torch.tensor(0.0), torch.tensor(4.0), torch.tensor(0.0))
    assert es.item() == pytest.approx(2 * (math.sqrt(2) - 1) / math.sqrt(math.pi))


def test_scores_reject_non_positive_variance():
    for score in (gaussian_nll_1d, energy_score_1d):
        with pytest.raises(ValueError, match="var must be > 0"):
            score(torch.zeros(2), torch.tensor([1.0, 0.0]), torch.zeros(2))
