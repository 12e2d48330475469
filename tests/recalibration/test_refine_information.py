"""Known answer: errors drawn from (P + s A)^-1 give back s; the posterior's curvature takes s."""

import math

import pytest
import torch

from ushape.recalibration.refine_information import (
    fit_information_scale,
    fit_sdf_recalibration,
    fit_sdf_recalibration_seen,
    refined_sdf_temperature,
    scaled_posterior_std,
    seen_floor_variance,
)


def test_the_information_scale_of_errors_drawn_with_a_known_scale_is_recovered():
    generator = torch.Generator().manual_seed(0)
    D, n, s_true = 6, 400, 0.125
    errors, precisions, informations = [], [], []
    for _ in range(n):
        precision = torch.diag(torch.rand(D, generator=generator, dtype=torch.float64) * 4 + 1)
        J = torch.randn(20, D, generator=generator, dtype=torch.float64)
        information = J.T @ J * 10
        cov = torch.linalg.inv(precision + s_true * information)
        errors.append(torch.linalg.cholesky(cov) @ torch.randn(D, generator=generator, dtype=torch.float64))
        precisions.append(precision)
        informations.append(information)
    scale, before, after = fit_information_scale(errors, precisions, informations)
    assert abs(math.log2(scale) - math.log2(s_true)) <= 0.5
    assert after < 0.03 < before


def test_scaled_std_is_the_prior_std_at_zero_and_shrinks_with_the_scale():
    precision = torch.diag(torch.tensor([4.0, 1.0]))
    information = torch.tensor([[10.0, 0.0], [0.0, 0.0]])
    assert torch.allclose(
        scaled_posterior_std(precision, information, 0.0), torch.tensor([0.5, 1.0], dtype=torch.float64)
    )
    assert scaled_posterior_std(precision, information, 1.0)[0] == pytest.approx(1 / math.sqrt(14))
    assert scaled_posterior_std(precision, information, 1.0)[1] == pytest.approx(1.0)  # an unseen dimension


def test_bad_input_says_what_to_pass():
    with pytest.raises(ValueError, match="one error, prior precision and information"):
        fit_information_scale([], [], [])


def test_the_refined_sdf_variance_gets_back_a_known_factor_and_floor():
    # Three groups (1, 3, 10 views: less posterior variance as views add up) whose errors carry T var + floor^2.
    gen = torch.Generator().manual_seed(3)
    factor, floor, groups = 2.0, 0.01, []
    for spread in (0.03, 0.01, 0.003):
        std = torch.rand(8000, generator=gen, dtype=torch.float64) * spread + 1e-4
        scale = (factor * std.square() + floor**2).sqrt()
        groups.append(((scale * torch.randn(8000, generator=gen, dtype=torch.float64)).abs(), std))
    found, found_floor, exponent, before, after = fit_sdf_recalibration(groups, misfit=0.014)
    # The floors tried are 2^(1/2) apart below the misfit (0.0099 is one): the fit lands within a step of each.
    assert found_floor == pytest.approx(floor, rel=0.45) and found == pytest.approx(factor, rel=0.45)
    assert max(after) < 0.03 and min(before) > 0.15  # within a grid step of calibrated, from far over-confident
    assert exponent == 0.0  # no view counts given: one factor for every group
    with pytest.raises(ValueError, match="at least one"):
        fit_sdf_recalibration([], misfit=0.01)


def test_seen_and_unseen_floors_drawn_apart_are_recovered_each_calibrated():
    # The errors carry T var + floor^2 with a small floor where a view saw the point and a larger one elsewhere;
    # one floor for all would be too wide on the seen points and too narrow on the unseen ones.
    gen = torch.Generator().manual_seed(5)
    factor, seen_floor, unseen_floor, groups = 1.0, 0.0025, 0.01, []
    for spread in (0.004, 0.002, 0.001):
        std = torch.rand(1500, generator=gen, dtype=torch.float64) * spread + 1e-4
        seen = torch.rand(1500, generator=gen) < 0.6
        scale = seen_floor_variance(std.square(), seen, factor, seen_floor, unseen_floor).sqrt()
        groups.append(((scale * torch.randn(1500, generator=gen, dtype=torch.float64)).abs(), std, seen))
    fit = fit_sdf_recalibration_seen(groups, misfit=0.01, grid=tuple(2.0 ** (k / 2) for k in range(-4, 5)))
    # The floors tried are 2^(1/2) apart up to the misfit (0.0025 and 0.01 are on the grid).
    assert fit["floor_seen"] == pytest.approx(seen_floor, rel=0.45)
    assert fit["floor_unseen"] == pytest.approx(unseen_floor, rel=0.45)
    assert max(fit["after_seen"] + fit["after_unseen"]) < 0.04 and min(fit["before"]) > 0.15
    one = fit_sdf_recalibration([(e, s) for e, s, _ in groups], misfit=0.01)  # a single floor: worse per part
    pooled = [
        float((e[k] / (one[0] * s[k].square() + one[1] ** 2).sqrt() < 0.6745).double().mean())
        for e, s, seen in groups
        for k in (seen, ~seen)
    ]  # the fraction inside the 50 % interval, seen then unseen: far from 0.5 on one side or both
    assert max(abs(p - 0.5) for p in pooled) > 0.1
    with pytest.raises(ValueError, match="at least one"):
        fit_sdf_recalibration_seen([], misfit=0.01)
    with pytest.raises(ValueError, match="must be equal"):
        fit_sdf_recalibration_seen([(torch.ones(3), torch.ones(3), torch.ones(2, dtype=torch.bool))], misfit=0.01)


def test_a_factor_that_grows_with_the_views_is_recovered_and_one_factor_for_all_is_worse():
    # Errors carry T n^beta var + floor^2 at n = 1, 3 and 10 views, beta = 0.4: the posterior's std shrinks
    # with the views faster than its error does. Fitted with the exponent, every count is calibrated; with
    # one factor, the worst count is not.
    gen = torch.Generator().manual_seed(11)
    factor, beta, floor, counts, groups = 0.5, 0.4, 0.004, (1, 3, 10), []
    for n, spread in zip(counts, (0.03, 0.015, 0.006)):
        std = torch.rand(6000, generator=gen, dtype=torch.float64) * spread + 1e-4
        scale = (factor * n**beta * std.square() + floor**2).sqrt()
        groups.append(((scale * torch.randn(6000, generator=gen, dtype=torch.float64)).abs(), std))
    fit = fit_sdf_recalibration(groups, misfit=0.008, view_counts=counts, exponents=(0.0, 0.2, 0.4, 0.6))
    assert fit.view_exponent == 0.4 and fit.temperature == pytest.approx(factor, rel=0.2)
    assert max(fit.after) < 0.03
    one = fit_sdf_recalibration(groups, misfit=0.008)
    assert one.view_exponent == 0.0 and max(one.after) > 2 * max(fit.after)
    # The seen model takes the same exponent.
    seen = [(e, s, torch.arange(len(e)) % 2 == 0) for e, s in groups]
    fit_seen = fit_sdf_recalibration_seen(
        seen, misfit=0.008, view_counts=counts, exponents=(0.0, 0.4), grid=tuple(2.0 ** (k / 4) for k in range(-8, 5))
    )
    assert fit_seen["sdf_view_exponent"] == 0.4 and max(fit_seen["after"]) < 0.04
    with pytest.raises(ValueError, match="one view count"):
        fit_sdf_recalibration(groups, misfit=0.008, view_counts=(1, 3), exponents=(0.0, 0.4))
    with pytest.raises(ValueError, match="needs view_counts"):
        fit_sdf_recalibration(groups, misfit=0.008, exponents=(0.0, 0.4))


def test_a_stored_fit_gives_its_factor_at_the_views_refined_on():
    assert refined_sdf_temperature({"sdf_temperature": 0.5, "sdf_view_exponent": 0.5}, 9) == pytest.approx(1.5)
    assert refined_sdf_temperature({"sdf_temperature": 0.5}, 9) == 0.5  # a fit stored before the exponent
    with pytest.raises(ValueError, match="number of views refined on"):
        refined_sdf_temperature({"sdf_temperature": 0.5}, 0)
