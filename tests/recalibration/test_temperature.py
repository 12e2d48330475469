"""Temperature scaling: the closed form must equal a numeric NLL minimiser and fix known mis-scaling."""

import math

import pytest
import torch
from scipy.optimize import minimize_scalar

from ushape.metrics.calibration import calibration_curve, calibration_error
from ushape.recalibration import (
    apply_temperature,
    fit_calibration_temperature_across,
    fit_calibration_temperature_and_floor,
    fit_temperature,
    floor_grid,
    gaussian_nll_with_temperature,
)
from ushape.recalibration.temperature import CALIBRATION_GRID


def _validation(scale, n=4000, d=16, seed=0):
    """Targets drawn with `scale` times the variance the model predicts."""
    gen = torch.Generator().manual_seed(seed)
    mu = torch.randn(n, d, generator=gen, dtype=torch.float64)
    var = torch.rand(n, d, generator=gen, dtype=torch.float64) + 0.05
    target = mu + (scale * var).sqrt() * torch.randn(n, d, generator=gen, dtype=torch.float64)
    return mu, var, target


def test_closed_form_equals_numeric_minimiser():
    mu, var, target = _validation(scale=2.5, n=500)
    closed = fit_temperature(mu, var, target)
    numeric = minimize_scalar(
        lambda log_t: gaussian_nll_with_temperature(mu, var, target, math.exp(log_t)),
        bounds=(-5, 5),
        method="bounded",
        options={"xatol": 1e-10},
    )
    assert closed == pytest.approx(math.exp(numeric.x), rel=1e-5)


def test_recovers_the_known_variance_scale():
    for scale in (0.25, 1.0, 4.0):
        mu, var, target = _validation(scale)
        assert fit_temperature(mu, var, target) == pytest.approx(scale, rel=0.03)


def test_scaling_repairs_an_overconfident_model():
    mu, var, target = _validation(scale=4.0, seed=1)
    temperature = fit_temperature(mu, var, target)
    abs_error = (target - mu).abs()
    before = calibration_error(*calibration_curve(abs_error, var.sqrt(), 50))
    after = calibration_error(*calibration_curve(abs_error, apply_temperature(var, temperature).sqrt(), 50))
    assert before > 0.1 and after < 0.01
    assert isinstance(temperature, float)


def test_apply_temperature_scales_variance():
    var = torch.tensor([1.0, 2.0])
    assert apply_temperature(var, 3.0).tolist() == [3.0, 6.0]
    for bad in (0.0, -1.0, float("nan"), float("inf"), "hot"):
        with pytest.raises(ValueError, match="temperature must be"):
            apply_temperature(var, bad)


def test_bad_validation_data():
    mu, var, target = _validation(1.0, n=4, d=2)
    with pytest.raises(ValueError, match="one shape"):
        fit_temperature(mu, var[:, :1], target)
    with pytest.raises(ValueError, match="var must be > 0"):
        fit_temperature(mu, torch.zeros_like(var), target)
    with pytest.raises(ValueError, match="NaN"):
        fit_temperature(mu, var, target * float("nan"))
    with pytest.raises(ValueError, match="no spread"):
        fit_temperature(mu, var, mu.clone())


def test_calibration_temperature_recovers_a_known_overconfidence():
    from ushape.recalibration.temperature import fit_calibration_temperature

    torch.manual_seed(0)
    std = torch.rand(200_000) * 0.05 + 0.01
    error = (torch.randn(200_000) * std * 1.3).abs()  # predicted std 1.3x too small: T = 1.69
    t, before, after = fit_calibration_temperature(error, std)
    assert t == pytest.approx(1.69, rel=0.1)
    assert after < 0.01 < before
    # Already calibrated: T stays 1 (ties go to the factor nearest 1).
    t, _, after = fit_calibration_temperature((torch.randn(200_000) * std).abs(), std)
    assert t == pytest.approx(1.0, rel=0.1) and after < 0.01
    with pytest.raises(ValueError, match="std >= 0"):
        fit_calibration_temperature(error, -std)


def _groups(factors, n=20000, seed=0):
    """(|error|, std) per group: std drawn per sample, errors Gaussian with `factor` times its variance."""
    gen = torch.Generator().manual_seed(seed)
    groups = []
    for factor in factors:
        std = torch.rand(n, generator=gen, dtype=torch.float64) * (0.1 + len(groups)) + 0.01
        groups.append(((math.sqrt(factor) * std * torch.randn(n, generator=gen, dtype=torch.float64)).abs(), std))
    return groups


def test_across_groups_gives_back_the_known_variance_scale():
    for factor in (0.5, 2.0, 4.0):
        found, before, after = fit_calibration_temperature_across(_groups([factor] * 3))
        assert found == pytest.approx(factor, rel=0.1)  # the grid is 2^(1/8) apart: within a step
        assert max(after) < 0.01 < min(before)  # calibrated at T, not at T = 1


def test_across_groups_minimises_the_worst_group():
    groups = _groups([1.0, 4.0])  # no one factor fits both: the worst group's error is balanced
    found, _, after = fit_calibration_temperature_across(groups)
    assert 1.0 < found < 4.0
    for own in (1.0, 4.0):  # either group's own factor leaves the other group worse than the balance
        assert max(after) < max(fit_calibration_temperature_across(groups, grid=(own,))[2])


def test_across_groups_with_a_known_floor_gives_back_the_variance_scale():
    # Errors drawn with variance T std^2 + floor^2: given the floor, the fit finds T, and calibrates only with it.
    gen = torch.Generator().manual_seed(1)
    floor, factor, groups = 0.05, 2.0, []
    for spread in (0.02, 0.1):
        std = torch.rand(30000, generator=gen, dtype=torch.float64) * spread + 0.005
        scale = (factor * std.square() + floor**2).sqrt()
        groups.append(((scale * torch.randn(30000, generator=gen, dtype=torch.float64)).abs(), std))
    found, before, after = fit_calibration_temperature_across(groups, floor=floor)
    assert found == pytest.approx(factor, rel=0.1) and max(after) < 0.01 < min(before)
    _, _, without = fit_calibration_temperature_across(groups)
    assert max(without) > 3 * max(after)  # no single factor makes up for a floor
    with pytest.raises(ValueError, match="floor"):
        fit_calibration_temperature_across(groups, floor=-0.1)


def test_the_floor_and_the_scale_are_found_together():
    # Errors drawn with variance T std^2 + floor^2 at two spreads of std: the joint fit gives back both, from a
    # grid that holds the floor only as one of its steps (scale / 2^(1/2) away from it on either side).
    gen = torch.Generator().manual_seed(2)
    floor, factor, groups = 0.04, 0.5, []
    for spread in (0.02, 0.1, 0.3):
        std = torch.rand(8000, generator=gen, dtype=torch.float64) * spread + 0.005
        scale = (factor * std.square() + floor**2).sqrt()
        groups.append(((scale * torch.randn(8000, generator=gen, dtype=torch.float64)).abs(), std))
    floors = floor_grid(0.04)
    assert floors[0] == 0.0 and floor in floors  # k = 0: the scale times 2.0 ** 0, the scale itself
    coarse = CALIBRATION_GRID[::2]  # 2^(1/4) apart, 0.5 on it
    found, found_floor, before, after = fit_calibration_temperature_and_floor(groups, floors, grid=coarse)
    assert found == pytest.approx(factor, rel=0.1) and found_floor == pytest.approx(floor)
    assert max(after) < 0.01 < min(before)
    _, floor0, _, no_floor = fit_calibration_temperature_and_floor(groups, (0.0,), grid=coarse)
    assert floor0 == 0.0 and max(no_floor) > 3 * max(after)
    with pytest.raises(ValueError, match="at least one"):
        fit_calibration_temperature_and_floor(groups, ())
    with pytest.raises(ValueError, match="scale"):
        floor_grid(0.0)


def test_across_groups_rejects_bad_input():
    with pytest.raises(ValueError, match="at least one"):
        fit_calibration_temperature_across([])
    with pytest.raises(ValueError, match="std >= 0"):
        fit_calibration_temperature_across([(torch.ones(3), -torch.ones(3))])
    with pytest.raises(ValueError, match="must be equal"):
        fit_calibration_temperature_across([(torch.ones(3), torch.ones(2))])
