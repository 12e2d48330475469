"""Monte Carlo and linearised propagation against exact answers and against each other."""

import pytest
import torch

from ushape.propagation import decode_points, frozen, propagate_linearised, propagate_mc


def _gaussian(d, scale, dtype=torch.float64):
    gen = torch.Generator().manual_seed(1)
    mu = torch.randn(d, generator=gen, dtype=dtype) * 0.3
    var = (torch.rand(d, generator=gen, dtype=dtype) + 0.5) * scale
    return mu, var


def _points(n, dtype=torch.float64):
    return torch.rand(n, 3, generator=torch.Generator().manual_seed(2), dtype=dtype) * 2 - 1


def test_linearised_is_exact_for_a_linear_decoder(linear_decoder):
    mu, var = _gaussian(6, 0.2)
    points = _points(50)
    mean, variance = propagate_linearised(linear_decoder, mu, var, points)
    with torch.no_grad():
        expected_mean = linear_decoder(points, mu)
        expected_var = (linear_decoder.w**2 * var).sum()
    assert torch.allclose(mean, expected_mean, atol=1e-12)
    assert torch.allclose(variance, expected_var.expand(50), rtol=1e-12)


def test_monte_carlo_converges_to_the_exact_variance(linear_decoder):
    mu, var = _gaussian(6, 0.2)
    points = _points(20)
    gen = torch.Generator().manual_seed(3)
    mean, variance = propagate_mc(linear_decoder, mu, var, points, n_samples=20000, generator=gen)
    with torch.no_grad():
        exact_var = (linear_decoder.w**2 * var).sum().item()
        exact_mean = linear_decoder(points, mu)
    # One shared set of codes for all points, so every point sees the same sampling error.
    assert variance.mean().item() == pytest.approx(exact_var, rel=0.03)
    assert torch.allclose(mean, exact_mean, atol=4 * (exact_var / 20000) ** 0.5)


def test_monte_carlo_and_linearised_agree_for_small_latent_spread(small_decoder):
    mu, var = _gaussian(8, 1e-4, torch.float32)
    points = _points(200, torch.float32)
    lin_mean, lin_var = propagate_linearised(small_decoder, mu, var, points)
    gen = torch.Generator().manual_seed(4)
    mc_mean, mc_var = propagate_mc(small_decoder, mu, var, points, n_samples=5000, generator=gen)
    ratio = mc_var / lin_var
    assert ratio.median().item() == pytest.approx(1.0, abs=0.05)
    assert ((ratio - 1).abs() < 0.3).float().mean().item() > 0.95
    assert torch.allclose(mc_mean, lin_mean, atol=3e-3 * lin_mean.abs().max().item() + 1e-4)


def test_monte_carlo_needs_two_samples(linear_decoder):
    mu, var = _gaussian(6, 0.1)
    with pytest.raises(ValueError, match="n_samples must be an integer >= 2"):
        propagate_mc(linear_decoder, mu, var, _points(4), n_samples=1)


def test_monte_carlo_returns_its_samples(small_decoder):
    mu, var = _gaussian(8, 0.01, torch.float32)
    points = _points(30, torch.float32)
    gen = torch.Generator().manual_seed(0)
    mean, variance, samples = propagate_mc(small_decoder, mu, var, points, 7, gen, return_samples=True)
    assert samples.shape == (7, 30)
    assert torch.allclose(mean, samples.mean(0)) and torch.allclose(variance, samples.var(0, unbiased=True))
    direct = small_decoder.eval()(points, mu)  # the decoder's mean is not its samples' mean
    assert not torch.allclose(direct, samples[0])


def test_chunking_does_not_change_results(small_decoder):
    mu, var = _gaussian(8, 0.01, torch.float32)
    points = _points(101, torch.float32)
    runs = [
        propagate_mc(small_decoder, mu, var, points, 5, torch.Generator().manual_seed(9), chunk=c) for c in (7, 4096)
    ]
    assert torch.allclose(runs[0][0], runs[1][0], atol=1e-6) and torch.allclose(runs[0][1], runs[1][1], atol=1e-7)
    lin = [propagate_linearised(small_decoder, mu, var, points, chunk=c) for c in (13, 4096)]
    assert torch.allclose(lin[0][0], lin[1][0], atol=1e-6) and torch.allclose(lin[0][1], lin[1][1], rtol=1e-5)
    plain = [decode_points(small_decoder, mu, points, chunk=c) for c in (3, 4096)]
    assert torch.allclose(plain[0], plain[1], atol=1e-6)


def test_decoder_state_is_restored_and_no_parameter_grads(small_decoder):
    small_decoder.train()
    mu, var = _gaussian(8, 0.01, torch.float32)
    propagate_linearised(small_decoder, mu, var, _points(16, torch.float32))
    assert small_decoder.training and all(m.training for m in small_decoder.modules())
    assert all(p.requires_grad and p.grad is None for p in small_decoder.parameters())


def test_dropout_is_off_while_propagating(small_decoder):
    small_decoder.train()
    mu, var = _gaussian(8, 0.01, torch.float32)
    points = _points(16, torch.float32)
    first = propagate_linearised(small_decoder, mu, var, points)
    second = propagate_linearised(small_decoder, mu, var, points)
    # Exact on purpose: the same call twice in one process differs only if dropout draws.
    assert torch.equal(first[0], second[0]) and torch.equal(first[1], second[1])
    with frozen(small_decoder):
        assert not small_decoder.training


def test_bf16_is_close_to_fp32(small_decoder):
    mu, var = _gaussian(8, 0.01, torch.float32)
    points = _points(64, torch.float32)
    mean32, var32 = propagate_linearised(small_decoder, mu, var, points)
    mean16, var16 = propagate_linearised(small_decoder, mu, var, points, bf16=True)
    assert mean16.dtype == torch.float32
    assert torch.allclose(mean16, mean32, atol=0.02 * mean32.abs().max().item())
    assert ((var16.sqrt() - var32.sqrt()).abs() / var32.sqrt()).median().item() < 0.05


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"mu": torch.zeros(6), "var": torch.ones(5)}, r"mu \[D\] and var \[D\]"),
        ({"mu": torch.zeros(6), "var": -torch.ones(6)}, "var must be >= 0"),
        ({"points": torch.zeros(4, 2)}, r"\[P, 3\]"),
        ({"chunk": 0}, "chunk"),
    ],
)
def test_bad_inputs_raise(linear_decoder, kwargs, message):
    args = {"mu": torch.zeros(6, dtype=torch.float64), "var": torch.ones(6, dtype=torch.float64), "points": _points(4)}
    args.update({k: v.double() if torch.is_tensor(v) else v for k, v in kwargs.items()})
    with pytest.raises(ValueError, match=message):
        propagate_linearised(linear_decoder, **args)
    with pytest.raises(ValueError, match=message):
        propagate_mc(linear_decoder, **args)


def test_decoding_refuses_nan_codes_and_codes_of_another_size(small_decoder):
    """A NaN code used to decode to an all-NaN field in silence; a code of the wrong length to a raw matmul error."""
    points = torch.zeros(4, 3)
    with pytest.raises(ValueError, match="NaN"):
        decode_points(small_decoder, torch.full((8,), float("nan")), points)
    with pytest.raises(ValueError, match="code has 5 dimensions but the decoder takes 8"):
        decode_points(small_decoder, torch.zeros(5), points)
    with pytest.raises(ValueError, match="code has 5 dimensions but the decoder takes 8"):
        propagate_linearised(small_decoder, torch.zeros(5), torch.ones(5), points)
    with pytest.raises(ValueError, match="code has 5 dimensions but the decoder takes 8"):
        propagate_mc(small_decoder, torch.zeros(5), torch.ones(5), points, n_samples=2)
    from ushape.propagation.field import decode_field

    with pytest.raises(ValueError, match="NaN"):
        decode_field(small_decoder, torch.tensor([float("nan")] * 8), resolution=2)
