"""Latent-space calibration curve and validation scores against known answers."""

import math

import pytest
import torch
from scipy import stats

from ushape.encoder.calibration import calibration_curve, calibration_error, probability_levels, two_sided_quantile
from ushape.encoder.latent_metrics import latent_l2, latent_scores, spearman_correlation


def test_two_sided_quantile_known_values():
    p = torch.tensor([math.erf(1 / math.sqrt(2)), 0.9973002, 0.5])
    assert torch.allclose(two_sided_quantile(p), torch.tensor([1.0, 3.0, 0.6744898], dtype=torch.float64), atol=1e-5)


def test_levels_lie_strictly_inside_zero_one():
    p = probability_levels(4)
    assert torch.allclose(p, torch.tensor([0.2, 0.4, 0.6, 0.8], dtype=torch.float64))


def test_calibrated_gaussian_errors_give_the_diagonal():
    g = torch.Generator().manual_seed(0)
    sigma = torch.rand(200_000, generator=g) + 0.1
    err = (torch.randn(200_000, generator=g) * sigma).abs()
    p, freq = calibration_curve(err, sigma, n_levels=9)
    assert torch.allclose(freq, p, atol=5e-3)
    assert calibration_error(p, freq).item() < 3e-3


def test_overconfident_predictions_fall_below_the_diagonal():
    g = torch.Generator().manual_seed(0)
    err = torch.randn(50_000, generator=g).abs()
    p, freq = calibration_curve(err, torch.full_like(err, 0.5), n_levels=9)  # true sigma 1, claimed 0.5
    assert (freq < p).all()
    # F_t = P(|X| <= Q(p_t) / 2) for X ~ N(0, 1)
    expected = torch.erf(two_sided_quantile(p) / 2 / math.sqrt(2))
    assert torch.allclose(freq, expected, atol=1e-2)


def test_calibration_curve_by_hand():
    err, sigma = torch.tensor([0.1, 1.0, 5.0]), torch.ones(3)
    p, freq = calibration_curve(err, sigma, n_levels=1)  # p = 0.5, Q = 0.674
    assert freq.tolist() == [pytest.approx(1 / 3)]
    with pytest.raises(ValueError, match="same size"):
        calibration_curve(err, torch.ones(2))


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
