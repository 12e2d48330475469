"""Known answers for the stage-1 losses."""

import math

import pytest
import torch

from ushape.decoder.losses import clamped_l1, code_prior, code_regulariser


def test_clamped_l1_clamps_both_sides():
    pred = torch.tensor([0.05, 0.5, -0.3, 0.02])
    target = torch.tensor([0.0, 0.2, 0.05, -0.5])
    # clamped: pred [0.05, 0.1, -0.1, 0.02], target [0, 0.1, 0.05, -0.1]
    expected = (0.05 + 0.0 + 0.15 + 0.12) / 4
    assert clamped_l1(pred, target, 0.1).item() == pytest.approx(expected, abs=1e-7)


def test_clamped_l1_far_field_with_right_sign_costs_nothing():
    assert clamped_l1(torch.tensor([0.7, -2.0]), torch.tensor([0.3, -0.2]), 0.1).item() == 0.0


def test_clamped_l1_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="same shape"):
        clamped_l1(torch.zeros(3), torch.zeros(3, 1), 0.1)


def test_code_regulariser_is_deepsdf_mean_norm_with_ramp():
    codes = torch.tensor([[3.0, 4.0], [0.0, 1.0]])  # norms 5 and 1, mean 3
    assert code_regulariser(codes, 1e-4, epoch=50, warmup_epochs=100).item() == pytest.approx(1e-4 * 0.5 * 3)
    assert code_regulariser(codes, 1e-4, epoch=250, warmup_epochs=100).item() == pytest.approx(1e-4 * 3)
    assert code_regulariser(codes, 2.0, epoch=1, warmup_epochs=0).item() == pytest.approx(6.0)


def test_code_regulariser_gradient_is_unit_direction():
    codes = torch.tensor([[3.0, 4.0]], requires_grad=True)
    code_regulariser(codes, 1.0, epoch=1, warmup_epochs=1).backward()
    assert torch.allclose(codes.grad, torch.tensor([[0.6, 0.8]]))


def test_code_prior_is_mean_square_per_code():
    codes = torch.tensor([[1.0, 3.0], [2.0, 0.0]])
    assert torch.allclose(code_prior(codes, 0.5), torch.tensor([0.5 * 5.0, 0.5 * 2.0]))
    assert not math.isnan(code_prior(torch.zeros(1, 4), 1.0).item())
