"""Calibration curves: calibrated, over- and under-confident Gaussians give known shapes."""

import matplotlib
import pytest
import torch

from ushape.metrics.calibration import (
    calibration_curve,
    calibration_error,
    calibration_error_interval,
    plot_calibration,
    probability_levels,
    two_sided_quantile,
)


def _errors(n=100_000, seed=0):
    gen = torch.Generator().manual_seed(seed)
    sigma = torch.rand(n, generator=gen, dtype=torch.float64) * 2 + 0.1
    return (sigma * torch.randn(n, generator=gen, dtype=torch.float64)).abs(), sigma


def test_two_sided_quantile_known_values():
    assert two_sided_quantile(torch.tensor(0.9973, dtype=torch.float64)).item() == pytest.approx(3.0, abs=1e-3)
    assert two_sided_quantile(torch.tensor(0.6827, dtype=torch.float64)).item() == pytest.approx(1.0, abs=1e-3)
    assert two_sided_quantile(torch.tensor(0.95, dtype=torch.float64)).item() == pytest.approx(1.96, abs=1e-3)


def test_levels_are_uniform_inside_the_open_interval():
    p = probability_levels(4)
    assert p.tolist() == [0.125, 0.375, 0.625, 0.875]


def test_calibrated_gaussian_follows_the_diagonal():
    abs_error, sigma = _errors()
    p, freq = calibration_curve(abs_error, sigma, n_levels=50)
    assert (freq - p).abs().max().item() < 0.01
    assert calibration_error(p, freq) < 0.005


def test_overconfident_is_below_and_underconfident_above():
    abs_error, sigma = _errors()
    p, over = calibration_curve(abs_error, sigma / 2, n_levels=20)
    _, under = calibration_curve(abs_error, sigma * 2, n_levels=20)
    assert (over < p).all() and (under > p).all()
    # Halving sigma: Pr(|X| <= Q(p)/2) is known exactly.
    expected = 2 * torch.special.ndtr(two_sided_quantile(p) / 2) - 1
    assert torch.allclose(over, expected, atol=0.01)


def test_small_known_counts():
    abs_error = torch.tensor([0.0, 0.5, 1.0, 2.0, 10.0])
    sigma = torch.ones(5)
    p, freq = calibration_curve(abs_error, sigma, n_levels=1)  # p = 0.5, Q(0.5) = 0.674
    assert p.item() == 0.5 and freq.item() == pytest.approx(2 / 5)


def test_zero_sigma_counts_exact_hits_only():
    p, freq = calibration_curve(torch.tensor([0.0, 0.1]), torch.tensor([0.0, 0.0]), n_levels=3)
    assert freq.tolist() == [0.5, 0.5, 0.5]


def test_multidimensional_inputs_are_flattened():
    abs_error, sigma = _errors(1000)
    flat = calibration_curve(abs_error, sigma, 10)[1]
    assert torch.equal(calibration_curve(abs_error.reshape(100, 10), sigma.reshape(100, 10), 10)[1], flat)


def test_calibration_error_known_value():
    p = torch.tensor([0.25, 0.75])
    assert calibration_error(p, torch.tensor([0.0, 1.0])) == pytest.approx(0.25)
    with pytest.raises(ValueError, match="same non-empty"):
        calibration_error(p, torch.tensor([0.1]))


@pytest.mark.parametrize(
    "abs_error, sigma, message",
    [
        (torch.ones(3), torch.ones(4), "one sigma per error"),
        (-torch.ones(3), torch.ones(3), "abs_error must be >= 0"),
        (torch.ones(3), -torch.ones(3), "sigma must be >= 0"),
        (torch.tensor([float("nan")]), torch.ones(1), "NaN"),
        (torch.ones(0), torch.ones(0), "empty"),
    ],
)
def test_bad_inputs(abs_error, sigma, message):
    with pytest.raises(ValueError, match=message):
        calibration_curve(abs_error, sigma)


def test_plot_has_diagonal_and_one_line_per_method(tmp_path):
    abs_error, sigma = _errors(2000)
    curves = {
        "ours": calibration_curve(abs_error, sigma, 20),
        "equal variance": calibration_curve(abs_error, torch.ones_like(sigma), 20),
    }
    fig = plot_calibration(curves, title="latent space")
    ax = fig.axes[0]
    assert isinstance(fig, matplotlib.figure.Figure)
    assert len(ax.lines) == 3 and ax.lines[0].get_linestyle() == "--"
    assert [t.get_text().split(" (")[0] for t in ax.get_legend().get_texts()] == ["ideal", "ours", "equal variance"]
    assert ax.get_title() == "latent space"
    fig.savefig(tmp_path / "calibration.png")
    assert (tmp_path / "calibration.png").stat().st_size > 1000
    with pytest.raises(ValueError, match="no curves"):
        plot_calibration({})


def test_the_shape_bootstrap_interval_holds_the_pooled_error_and_widens_with_shapes_that_disagree():
    gen = torch.Generator().manual_seed(0)
    errors = [(torch.randn(500, generator=gen, dtype=torch.float64)).abs() for _ in range(8)]
    sigmas = [torch.ones(500, dtype=torch.float64) for _ in range(8)]
    pooled = calibration_error(*calibration_curve(torch.cat(errors), torch.cat(sigmas), 20))
    low, high = calibration_error_interval(errors, sigmas)
    assert low <= pooled <= high and high < 0.05  # calibrated shapes: a narrow interval near 0
    # One shape repeated: every draw is the same data, so the interval is the error itself.
    same = calibration_error_interval([errors[0]] * 5, [sigmas[0]] * 5)
    one = calibration_error(*calibration_curve(errors[0], sigmas[0], 20))
    assert same == pytest.approx((one, one))
    # Half the shapes 3x over-confident: which half a draw holds moves the error a lot.
    mixed = [e * (3.0 if i % 2 else 1.0) for i, e in enumerate(errors)]
    low_mixed, high_mixed = calibration_error_interval(mixed, sigmas)
    assert high_mixed - low_mixed > 3 * (high - low)
    with pytest.raises(ValueError, match="per shape"):
        calibration_error_interval([], [])
