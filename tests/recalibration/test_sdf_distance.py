"""The SDF variance with a term in the distance from the surface: known T and b come back from drawn errors."""

import pytest
import torch

from ushape.recalibration import DistanceFit, distance_variance, fit_sdf_distance_calibration
from ushape.recalibration.sdf_distance import DISTANCE_GRID, FACTOR_GRID


def _groups(temperature, floor, distance_scale, n=5000, n_groups=3, seed=0):
    """(|error|, variance, clamped mean) per group, errors drawn from N(0, T var + floor^2 + (b |mean|)^2)."""
    gen = torch.Generator().manual_seed(seed)
    groups = []
    for g in range(n_groups):
        var = (0.02 + 0.02 * torch.rand(n, generator=gen, dtype=torch.float64)).square() / (g + 1)
        mean = (0.3 * torch.rand(n, generator=gen, dtype=torch.float64) - 0.15).clamp(-0.1, 0.1)
        std = distance_variance(var, mean, temperature, floor, distance_scale).sqrt()
        groups.append(((std * torch.randn(n, generator=gen, dtype=torch.float64)).abs(), var, mean))
    return groups


def test_distance_variance_is_the_sum_of_its_terms():
    var, mean = torch.tensor([0.01, 0.04]), torch.tensor([0.0, -0.1])
    got = distance_variance(var, mean, 0.5, 0.02, 0.6)
    assert torch.allclose(got, torch.tensor([0.005 + 0.0004, 0.02 + 0.0004 + 0.0036]))


def test_gives_back_a_known_factor_and_distance_scale():
    b = DISTANCE_GRID[14]  # 0.05 * 2^3.5, on the grid
    fit = fit_sdf_distance_calibration(_groups(0.5, 0.01, b), floor=0.01)
    assert isinstance(fit, DistanceFit)
    assert fit.temperature == pytest.approx(0.5, rel=0.2) and fit.distance_scale == pytest.approx(b, rel=0.2)
    assert max(fit.after) < 0.02 < min(fit.before)  # calibrated at the fit; over-confident far out before it
    assert fit.worst >= max(fit.after)  # the worst also counts the samples near the surface


def test_no_distance_term_where_the_error_does_not_grow_with_the_distance():
    fit = fit_sdf_distance_calibration(_groups(2.0, 0.0, 0.0))
    assert fit.distance_scale == 0.0 and fit.temperature == pytest.approx(2.0, rel=0.2)


def test_a_term_the_pooled_fit_would_trade_against_the_surface_is_kept_calibrated_there():
    # Far from the surface the error is large; a factor alone would over-cover the surface and under-cover far out.
    groups = _groups(1.0, 0.0, DISTANCE_GRID[16])
    fit = fit_sdf_distance_calibration(groups, factors=FACTOR_GRID, distance_scales=(0.0,))
    with_term = fit_sdf_distance_calibration(groups)
    assert with_term.worst < fit.worst / 2


def test_rejects_bad_input():
    e, v, m = torch.ones(4), torch.ones(4), torch.zeros(4)
    with pytest.raises(ValueError, match="at least one"):
        fit_sdf_distance_calibration([])
    with pytest.raises(ValueError, match="floor"):
        fit_sdf_distance_calibration([(e, v, m)], floor=-1.0)
    with pytest.raises(ValueError, match="equal and non-empty"):
        fit_sdf_distance_calibration([(e, v, m[:2])])
    with pytest.raises(ValueError, match="variance >= 0"):
        fit_sdf_distance_calibration([(e, -v, m)])


def test_its_calibration_error_is_the_metric_s():
    from ushape.metrics.calibration import calibration_curve, calibration_error

    groups = _groups(0.5, 0.0, 0.3, n=2000)
    fit = fit_sdf_distance_calibration(groups, factors=(0.7,), distance_scales=(0.2,))
    expected = [
        calibration_error(*calibration_curve(e, distance_variance(v, m, 0.7, 0.0, 0.2).sqrt(), 20))
        for e, v, m in groups
    ]
    assert fit.after == pytest.approx(expected, abs=1e-12)
