"""The Gaussian head's soft log-variance clamp and the ImageEncoder's interface."""

import pytest
import torch

from ushape.encoder.heads import GaussianHead, ImageEncoder, soft_clamp


def test_soft_clamp_is_identity_at_the_midpoint_and_bounded():
    x = torch.tensor([-1e6, -4.0, 1e6], requires_grad=True)
    y = soft_clamp(x, -12.0, 4.0)
    assert y[1].item() == pytest.approx(-4.0)
    assert -12.0 <= y[0].item() < -11.99 and 3.99 < y[2].item() <= 4.0
    mid = torch.tensor(-4.0, requires_grad=True)
    soft_clamp(mid, -12.0, 4.0).backward()
    assert mid.grad.item() == pytest.approx(1.0)
    outside = torch.tensor(10.0, requires_grad=True)
    soft_clamp(outside, -12.0, 4.0).backward()
    assert outside.grad.item() > 0  # unlike a hard clamp, a saturated variance can still come back


def test_head_starts_at_the_midpoint_variance_and_stays_in_range():
    head = GaussianHead(in_dim=5, latent_size=3, logvar_min=-6, logvar_max=2)
    mu, logvar = head(torch.randn(4, 5))
    assert mu.shape == logvar.shape == (4, 3)
    assert torch.allclose(logvar, torch.full_like(logvar, -2.0))
    with torch.no_grad():
        head.logvar.weight.fill_(100.0)
    _, logvar = head(torch.full((1, 5), 10.0))
    assert (logvar <= 2).all() and (logvar > -6).all()


def test_head_rejects_an_empty_range():
    with pytest.raises(ValueError, match="below"):
        GaussianHead(4, logvar_min=1.0, logvar_max=1.0)


def test_image_encoder_shapes_and_normalisation(tiny_encoder):
    encoder = ImageEncoder(**tiny_encoder).eval()
    mu, logvar = encoder(torch.rand(2, 3, 32, 32))
    assert mu.shape == logvar.shape == (2, tiny_encoder["latent_size"])
    assert torch.allclose(encoder.pixel_mean.flatten(), torch.tensor([0.485, 0.456, 0.406]))
    assert "pixel_mean" not in encoder.state_dict()


def test_image_encoder_bad_input(tiny_encoder):
    encoder = ImageEncoder(**tiny_encoder)
    with pytest.raises(ValueError, match=r"\[B, 3, H, W\]"):
        encoder(torch.rand(2, 4, 32, 32))
    with pytest.raises(ValueError, match="_target_"):
        ImageEncoder(backbone={"pretrained": False})


def test_head_started_at_a_gaussian_predicts_it_for_any_features():
    head = GaussianHead(in_dim=16, latent_size=4)
    mean, var = torch.tensor([0.5, -0.2, 0.0, 1.0]), torch.tensor([0.1, 0.01, 1e-3, 2.0])
    head.start_at(mean, var)
    mu, logvar = head(torch.randn(5, 16))
    assert torch.allclose(mu, mean.expand(5, 4))
    assert torch.allclose(logvar, var.log().expand(5, 4), atol=1e-4)
    head.start_at(mean, torch.tensor([1e-30, 1.0, 1.0, 1e30]))  # beyond the clamp: kept just inside it
    _, logvar = head(torch.randn(2, 16))
    assert torch.isfinite(logvar).all() and (logvar > head.logvar_min).all() and (logvar < head.logvar_max).all()


def test_mixture_moments_of_two_members_by_hand():
    from ushape.encoder.heads import mixture_moments

    mu = torch.tensor([[[0.0, 1.0]], [[2.0, 1.0]]])  # [E=2, B=1, D=2]
    var = torch.tensor([[[1.0, 0.5]], [[3.0, 0.5]]])
    mean, logvar = mixture_moments(mu, var.log())
    assert torch.allclose(mean, torch.tensor([[1.0, 1.0]]))
    # var = mean of variances (2, 0.5) + spread of means (1, 0)
    assert torch.allclose(logvar.exp(), torch.tensor([[3.0, 0.5]]))


def test_ensemble_members_see_a_fixed_share_of_the_shapes():
    from ushape.encoder.heads import GaussianEnsemble

    head = GaussianEnsemble(in_dim=6, latent_size=3, members=4, keep=0.5, hidden=5)
    ids = [f"shape_{i}" for i in range(400)]
    share = head.member_of(ids)
    assert share.shape == (4, 400) and torch.equal(share, head.member_of(ids))
    assert 0.4 < share.float().mean() < 0.6
    assert not torch.equal(share[0], share[1])  # members see different shapes
    mu, logvar = head(torch.randn(7, 6))
    assert mu.shape == logvar.shape == (7, 3) and head.latent_size == 3
    head.start_at(torch.ones(3), torch.full((3,), 0.2))
    mu, logvar = head(torch.randn(2, 6))
    assert torch.allclose(mu, torch.ones(2, 3)) and torch.allclose(logvar.exp(), torch.full((2, 3), 0.2), rtol=1e-4)
