"""Latent-space validation scores against known answers (calibration maths: tests/evaluation)."""

import math

import pytest
import torch
from scipy import stats

from ushape.encoder.latent_metrics import latent_l2, latent_scores, spearman_correlation


def test_spearman_matches_scipy_including_ties():
    g = torch.Generator().manual_seed(0)
    x, y = torch.randn(50, generator=g), torch.randn(50, generator=g)
    x[::5] = 0.0  # ties
    ours = spearman_correlation(x, y).item()
    assert ours == pytest.approx(stats.spearmanr(x.numpy(), y.numpy()).statistic, abs=1e-10)
    assert spearman_correlation(x, x.exp()).item() == pytest.approx(1.0)
    assert math.isnan(spearman_correlation(torch.ones(5), y[:5]).item())


def test_latent_scores_reward_variance_that_tracks_the_error():
    g = torch.Generator().manual_seed(0)
    n, d = 400, 8
    sigma = torch.rand(n, 1, generator=g).expand(n, d) * 0.5 + 0.01
    target = torch.randn(n, d, generator=g)
    mu = target + sigma * torch.randn(n, d, generator=g)
    good = latent_scores(mu, 2 * sigma.log(), target, n_samples=200, generator=torch.Generator().manual_seed(1))
    flat = latent_scores(mu, torch.zeros(n, d), target, n_samples=200, generator=torch.Generator().manual_seed(1))
    assert good["latent_l2"].item() == pytest.approx(latent_l2(mu, target).item())
    assert good["rank_corr"].item() > 0.7
    assert good["calibration_error"].item() < 0.03 < flat["calibration_error"].item()
    assert good["latent_nll"] < flat["latent_nll"] and good["latent_es"] < flat["latent_es"]
    assert math.isnan(flat["rank_corr"].item())
