"""Every propagation method is a YAML file naming its function; `propagate` gives each the options it takes."""

import pytest
import torch

from ushape.propagation.mesh import METHODS, propagate, propagator


def test_every_method_file_names_a_function_and_unknown_ones_are_refused(linear_decoder):
    assert set(METHODS) >= {"mc", "linearised"}
    assert all(callable(propagator(m)) for m in METHODS)
    with pytest.raises(ValueError, match=r"unknown propagation method 'exact'; choose one of"):
        propagate(linear_decoder, torch.zeros(6), torch.ones(6), torch.zeros(1, 3), method="exact")


def test_by_name_each_method_finds_a_linear_decoders_variance(linear_decoder):
    """s(x, z) linear in z with weights w: the variance is sum_d w_d^2 var_d at every point, exactly for
    linearised and within the sampling error for Monte Carlo (the samples and the generator reach it)."""
    var = torch.linspace(0.05, 0.3, 6, dtype=torch.float64)
    points = torch.rand(7, 3, generator=torch.Generator().manual_seed(2), dtype=torch.float64) * 2 - 1
    exact = (linear_decoder.w**2 * var).sum().item()
    _, linearised = propagate(linear_decoder, torch.zeros(6, dtype=torch.float64), var, points, "linearised")
    assert torch.allclose(linearised, torch.full((7,), exact, dtype=torch.float64), rtol=1e-12)
    generator = torch.Generator().manual_seed(3)
    _, sampled = propagate(linear_decoder, torch.zeros(6, dtype=torch.float64), var, points, "mc", 20000, generator)
    assert sampled.mean().item() == pytest.approx(exact, rel=0.03)
