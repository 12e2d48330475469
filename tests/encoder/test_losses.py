"""Known answers for the latent-space losses."""

import math

import numpy as np
import pytest
import scoringrules as sr
import torch

from ushape.encoder.losses import energy_score, energy_score_from_samples, ensemble_loss, gaussian_nll, l2_loss


def paper_es_numpy(samples, target):
    """The paper's estimator written out with loops: samples [B, M, D], target [B, D]."""
    scores = []
    for z_m, z in zip(samples, target):
        m = len(z_m)
        first = sum(np.linalg.norm(z_m[i] - z) for i in range(m)) / m
        second = sum(np.linalg.norm(z_m[i] - z_m[i + 1]) for i in range(m - 1)) / (2 * (m - 1))
        scores.append(first - second)
    return float(np.mean(scores))


def test_es_estimator_matches_the_papers_formula_on_fixed_samples():
    samples, target = torch.randn(3, 50, 4, dtype=torch.float64), torch.randn(3, 4, dtype=torch.float64)
    ours = energy_score_from_samples(samples, target).item()
    assert ours == pytest.approx(paper_es_numpy(samples.numpy(), target.numpy()), rel=1e-12)


def test_es_agrees_with_scoringrules_fair_estimator_on_one_ensemble():
    """Both are unbiased for the same Energy Score; on the same ensembles they differ by MC noise only.

    scoringrules' fair estimator averages all M(M-1) pairs, the paper's the M-1 consecutive ones:
    with M = 1000 and 8 predictions the gap's standard deviation is ~0.2% of the score.
    """
    g = torch.Generator().manual_seed(1)
    samples = 0.3 * torch.randn(8, 1000, 16, generator=g, dtype=torch.float64) + 0.1
    target = torch.randn(8, 16, generator=g, dtype=torch.float64) * 0.2
    ours = energy_score_from_samples(samples, target).item()
    ref = np.mean(
        [sr.es_ensemble(y, x, estimator="fair", backend="numpy") for y, x in zip(target.numpy(), samples.numpy())]
    )
    assert ours == pytest.approx(ref, rel=1e-2)
    assert ours != pytest.approx(ref, rel=1e-9)  # two estimators, not the same computation


def test_es_expectation_in_one_dimension_is_the_gaussian_crps():
    """In 1-D the Energy Score is the CRPS, which has a closed form for a Gaussian."""
    mu, sigma, y = torch.tensor([[0.3]]), 0.7, torch.tensor([[1.1]])
    logvar = torch.full_like(mu, 2 * math.log(sigma))
    g = torch.Generator().manual_seed(0)
    mc = torch.stack([energy_score(mu, logvar, y, n_samples=20000, generator=g) for _ in range(5)]).mean()
    closed = sr.crps_normal(y.item(), mu.item(), sigma, backend="numpy")
    assert mc.item() == pytest.approx(float(closed), rel=1e-2)


def test_es_at_the_mean_in_d_dimensions_has_its_closed_form():
    """target = mu: ES = sigma c_D (1 - 1/sqrt 2), c_D = E||N(0, I_D)|| = sqrt 2 G((D+1)/2) / G(D/2)."""
    d, sigma = 64, 0.05
    c_d = math.sqrt(2) * math.exp(math.lgamma((d + 1) / 2) - math.lgamma(d / 2))
    mu = torch.zeros(32, d)
    es = energy_score(
        mu, torch.full_like(mu, 2 * math.log(sigma)), mu, n_samples=1000, generator=torch.Generator().manual_seed(0)
    )
    assert es.item() == pytest.approx(sigma * c_d * (1 - 1 / math.sqrt(2)), rel=1e-2)


def test_es_of_a_tight_gaussian_at_the_target_is_about_zero_and_far_one_is_large():
    z = torch.randn(4, 64)
    tight = energy_score(z, torch.full_like(z, -30.0), z, n_samples=100)
    assert tight.item() == pytest.approx(0.0, abs=1e-5)
    far = energy_score(z + 1.0, torch.full_like(z, -30.0), z, n_samples=100)
    assert far.item() == pytest.approx(8.0, rel=1e-4)  # ||1_64|| = 8


def test_es_gradient_reaches_mu_and_logvar_and_points_the_right_way():
    target = torch.zeros(2, 8)
    mu = torch.full((2, 8), 0.5, requires_grad=True)
    logvar = torch.full((2, 8), 2.0, requires_grad=True)  # far too wide
    energy_score(mu, logvar, target, n_samples=500, generator=torch.Generator().manual_seed(0)).backward()
    assert (mu.grad > 0).all()  # lowering mu towards the target lowers the score
    assert (logvar.grad > 0).all()  # so does narrowing the too-wide distribution


def test_es_is_reproducible_with_a_generator():
    mu, logvar, z = torch.randn(3, 5), torch.randn(3, 5), torch.randn(3, 5)
    a = energy_score(mu, logvar, z, 100, generator=torch.Generator().manual_seed(7))
    b = energy_score(mu, logvar, z, 100, generator=torch.Generator().manual_seed(7))
    assert a.item() == b.item()


def test_nll_is_the_true_negative_log_likelihood_minus_the_constant():
    mu, logvar, z = (
        torch.randn(5, 7, dtype=torch.float64),
        torch.randn(5, 7, dtype=torch.float64),
        torch.randn(5, 7, dtype=torch.float64),
    )
    true_nll = -torch.distributions.Normal(mu, torch.exp(0.5 * logvar)).log_prob(z).sum(-1).mean()
    assert gaussian_nll(mu, logvar, z).item() == pytest.approx(
        true_nll.item() - 0.5 * 7 * math.log(2 * math.pi), rel=1e-12
    )


def test_nll_by_hand():
    # one sample, D = 2: error (1, 2), variances (1, 4): 0.5 * (1 + 1 + 0 + log 4)
    mu, z = torch.tensor([[1.0, 2.0]]), torch.zeros(1, 2)
    logvar = torch.log(torch.tensor([[1.0, 4.0]]))
    assert gaussian_nll(mu, logvar, z).item() == pytest.approx(0.5 * (2 + math.log(4)), rel=1e-6)


def test_nll_gradient_drives_the_variance_towards_the_squared_error():
    mu, z = torch.zeros(1, 1), torch.full((1, 1), 0.5)
    logvar = torch.tensor([[math.log(0.25)]], requires_grad=True)  # sigma^2 = error^2: the optimum
    gaussian_nll(mu, logvar, z).backward()
    assert logvar.grad.abs().item() < 1e-6


def test_l2_is_the_mean_squared_error_and_ignores_logvar():
    mu, z = torch.tensor([[1.0, 3.0], [0.0, 0.0]]), torch.zeros(2, 2)
    assert l2_loss(mu, None, z).item() == pytest.approx(10 / 4)
    assert l2_loss(mu, torch.randn(2, 2), z).item() == pytest.approx(10 / 4)


@pytest.mark.parametrize("loss", [gaussian_nll, energy_score])
def test_shape_mismatch_is_a_clear_error(loss):
    with pytest.raises(ValueError, match=r"\[B, D\]"):
        loss(torch.zeros(2, 3), torch.zeros(2, 3), torch.zeros(2, 4))


def test_es_needs_two_samples():
    with pytest.raises(ValueError, match="n_samples >= 2"):
        energy_score(torch.zeros(1, 2), torch.zeros(1, 2), torch.zeros(1, 2), n_samples=1)


def _ensemble_grads(cross_fit: bool):
    torch.manual_seed(0)
    mus = torch.randn(2, 6, 3, requires_grad=True)
    logvars = torch.randn(2, 6, 3, requires_grad=True)
    member_of = torch.tensor([[True, True, True, False, False, False], [False, True, False, True, False, True]])
    ensemble_loss(gaussian_nll, mus, logvars, torch.randn(6, 3), member_of, cross_fit).backward()
    return mus.grad.abs().sum(-1) > 0, logvars.grad.abs().sum(-1) > 0, member_of


def test_plain_ensemble_loss_fits_each_member_on_its_own_share_only():
    mean_moves, var_moves, member_of = _ensemble_grads(cross_fit=False)
    assert torch.equal(mean_moves, member_of) and torch.equal(var_moves, member_of)


def test_cross_fitted_ensemble_loss_fits_the_variance_on_the_rows_the_mean_never_saw():
    mean_moves, var_moves, member_of = _ensemble_grads(cross_fit=True)
    assert torch.equal(mean_moves, member_of) and torch.equal(var_moves, ~member_of)


def test_ensemble_loss_by_hand_and_its_shape_checks():
    mus, logvars = torch.zeros(2, 2, 1), torch.zeros(2, 2, 1)
    target = torch.tensor([[1.0], [3.0]])
    member_of = torch.tensor([[True, False], [False, True]])
    # member 0 scores row 0 (0.5 * 1), member 1 row 1 (0.5 * 9): mean 2.5
    assert ensemble_loss(gaussian_nll, mus, logvars, target, member_of).item() == pytest.approx(2.5)
    # cross-fitted, each member also scores the other row with its variance: 0.5 * (1 + 9) per member
    assert ensemble_loss(gaussian_nll, mus, logvars, target, member_of, cross_fit=True).item() == pytest.approx(5.0)
    with pytest.raises(ValueError, match="member_of must be bool"):
        ensemble_loss(gaussian_nll, mus, logvars, target, member_of.float())
    with pytest.raises(ValueError, match=r"\[E, B, D\]"):
        ensemble_loss(gaussian_nll, mus[0], logvars[0], target, member_of)


def test_cross_fit_needs_an_ensemble_that_leaves_shapes_out():
    from ushape.encoder.heads import GaussianEnsemble

    with pytest.raises(ValueError, match="keep must be < 1"):
        GaussianEnsemble(in_dim=4, latent_size=2, members=3, keep=1.0, cross_fit=True)
