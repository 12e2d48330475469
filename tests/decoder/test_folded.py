"""The folded decoder gives the module's SDF and autograd's latent Jacobian, in float64 to roundoff."""

import pytest
import torch
from torch import nn

from ushape.decoder.folded import fold_code
from ushape.decoder.network import DeepSDFDecoder
from ushape.decoder.query import code_sdf_fn, frozen
from ushape.propagation.linearised import latent_jacobian

SHAPES = [
    dict(latent_size=8, hidden_dims=(32, 32, 32, 32), latent_in=(2,), dropout=0.0, weight_norm=True),
    dict(latent_size=5, hidden_dims=(16,) * 6, latent_in=(1, 4), dropout=0.2, weight_norm=True, output_tanh=False),
    dict(latent_size=3, hidden_dims=(16, 16), latent_in=(), dropout=0.0, weight_norm=False),
]


def decoder_and_code(spec: dict, seed: int = 0) -> tuple[DeepSDFDecoder, torch.Tensor]:
    torch.manual_seed(seed)
    decoder = DeepSDFDecoder(**spec).double().eval()
    with torch.no_grad():  # non-trivial weight-norm gains, so folding them in is tested
        for name, param in decoder.named_parameters():
            if name.endswith("original0"):
                param.mul_(torch.rand_like(param) + 0.5)
    return decoder, 0.3 * torch.randn(spec["latent_size"], dtype=torch.float64)


@pytest.mark.parametrize("spec", SHAPES)
def test_folded_sdf_and_jacobian_match_module_and_autograd(spec):
    decoder, code = decoder_and_code(spec)
    points = torch.rand(500, 3, dtype=torch.float64) * 2 - 1
    with frozen(decoder):
        folded = fold_code(decoder, code)
        expected_sdf, expected_jacobian = latent_jacobian(decoder, code, points)
        sdf, jacobian = folded.sdf_and_jacobian(points)
        torch.testing.assert_close(folded.sdf(points), decoder(points, code), rtol=0, atol=1e-12)
    torch.testing.assert_close(sdf, expected_sdf, rtol=0, atol=1e-12)
    assert jacobian.shape == (500, spec["latent_size"])
    torch.testing.assert_close(jacobian, expected_jacobian, rtol=1e-9, atol=1e-12)
    assert jacobian.abs().max() > 1e-3  # a real Jacobian, not zeros


@pytest.mark.parametrize("spec", SHAPES)
def test_spatial_gradient_matches_autograd(spec):
    decoder, code = decoder_and_code(spec, seed=1)
    points = (torch.rand(300, 3, dtype=torch.float64) * 2 - 1).requires_grad_(True)
    with frozen(decoder):
        (expected,) = torch.autograd.grad(decoder(points, code).sum(), points)
        _, jacobian, spatial = fold_code(decoder, code).sdf_and_gradients(points.detach())
        _, jacobian_only = fold_code(decoder, code).sdf_and_jacobian(points.detach())
    torch.testing.assert_close(spatial, expected, rtol=1e-9, atol=1e-12)
    # Two code paths (with and without the spatial gradient): the same Jacobian to float64 rounding.
    torch.testing.assert_close(jacobian, jacobian_only, rtol=1e-12, atol=1e-15)


def test_code_sdf_fn_uses_the_folded_decoder_and_returns_float32():
    decoder, code = decoder_and_code(SHAPES[0])
    points = torch.rand(100, 3, dtype=torch.float64) * 2 - 1
    with frozen(decoder):
        values = code_sdf_fn(decoder, code)(points)
        expected = decoder(points, code)
    assert values.dtype == torch.float32
    torch.testing.assert_close(values, expected.float())


class Scaled(DeepSDFDecoder):
    def forward(self, xyz, z):
        return 2 * super().forward(xyz, z)


def test_what_cannot_be_folded_is_left_to_the_module():
    decoder, code = decoder_and_code(SHAPES[1])  # dropout 0.2
    assert fold_code(decoder.train(), code) is None  # dropout would be on
    assert fold_code(decoder.eval(), code) is not None
    assert fold_code(Scaled(latent_size=3, hidden_dims=(8, 8), latent_in=()), torch.zeros(3)) is None
    assert fold_code(nn.Linear(3, 1), torch.zeros(3)) is None
    with pytest.raises(ValueError, match=r"code must be \[5\]"):
        fold_code(decoder.eval(), torch.zeros(4, dtype=torch.float64))


def test_multiply_adds_count_every_product():
    decoder, code = decoder_and_code(SHAPES[0])  # 8 -> 32 (skip at 2: 32 - 11 out, then 21 + 8 + 3 in) -> 32 -> 32 -> 1
    with frozen(decoder):
        forward, backward = fold_code(decoder, code).multiply_adds()
    assert forward == 32 * 3 + 21 * 32 + 32 * 24 + 32 * 32 + 1 * 32
    # backward: through layers 4..1 (their hidden weights) plus the code columns of layers 0 and 2
    assert backward == 1 * 32 + 32 * 32 + 32 * 21 + 21 * 32 + 32 * 8 + 32 * 8


def test_code_sdf_fn_takes_float32_points_for_a_float64_decoder():
    """Extraction hands float32 points; a float64 decoder still answers, in float32, as it did."""
    torch.manual_seed(0)
    decoder = DeepSDFDecoder(latent_size=4, hidden_dims=[16, 16], latent_in=[1], dropout=0.0).double().eval()
    code = 0.1 * torch.randn(4, dtype=torch.float64)
    points = torch.rand(50, 3) * 2 - 1
    values = code_sdf_fn(decoder, code)(points)
    assert values.dtype == torch.float32
    with torch.no_grad():
        expected = decoder(points.double(), code).float()
    assert torch.allclose(values, expected, atol=1e-6)


def float32_decoder_and_code(seed: int = 0) -> tuple[DeepSDFDecoder, torch.Tensor]:
    decoder, code = decoder_and_code(SHAPES[0], seed)
    return decoder.float(), code.float()


def test_bf16_fold_multiplies_hidden_features_in_bf16_and_keeps_the_rest_float32():
    decoder, code = float32_decoder_and_code()
    with frozen(decoder):
        folded = fold_code(decoder, code, bf16=True)
    assert folded.low == torch.bfloat16
    *inner, last = folded.layers
    assert all(layer.hidden is None or layer.hidden.dtype == torch.bfloat16 for layer in inner)
    assert all(layer.code is None or layer.code.dtype == torch.bfloat16 for layer in inner)
    assert all(layer.xyz is None or layer.xyz.dtype == torch.float32 for layer in folded.layers)
    assert last.hidden.dtype == torch.float32 and all(layer.bias.dtype == torch.float32 for layer in folded.layers)


def test_bf16_fold_never_rounds_the_point():
    """Two points closer than bf16's spacing at 0.7 (2^-8): autocast makes them one, the bf16 fold does not."""
    decoder, code = float32_decoder_and_code()
    points = torch.tensor([[0.7, 0.2, -0.3], [0.7 + 4e-4, 0.2, -0.3]])
    with frozen(decoder), torch.no_grad():
        with torch.autocast("cpu", dtype=torch.bfloat16):
            rounded = decoder(points, code).float()
        folded = fold_code(decoder, code, bf16=True).sdf(points)
    # autocast rounds both to one bf16 point: distinct bf16 values in [0.5, 1) lie 2^-8 apart, so two casts
    # closer than half that are the same value. The two rows of its product then hold the same numbers; their
    # outputs agree to within one bf16 step of the value (2^-8 relative), which a kernel that rounds the two
    # rows differently may still give. The fold keeps them 3e-6 apart.
    as_bf16 = points.bfloat16().float()
    assert float((as_bf16[0] - as_bf16[1]).abs().max()) < 2**-9
    assert abs(float(rounded[0] - rounded[1])) <= 2**-8 * abs(float(rounded[0]))
    assert folded[0] != folded[1]


def test_bf16_fold_is_close_to_float32_in_value_and_jacobian():
    decoder, code = float32_decoder_and_code(seed=2)
    points = torch.rand(2000, 3) * 2 - 1
    with frozen(decoder), torch.no_grad():
        sdf, jacobian = fold_code(decoder, code).sdf_and_jacobian(points)
        low_sdf, low_jacobian = fold_code(decoder, code, bf16=True).sdf_and_jacobian(points)
    assert low_sdf.dtype == low_jacobian.dtype == torch.float32
    assert not torch.equal(low_sdf, sdf)  # it really ran in bf16
    scale = sdf.abs().max()
    assert (low_sdf - sdf).abs().max() <= 0.02 * scale
    relative = (low_jacobian - jacobian).norm(dim=1) / jacobian.norm(dim=1)
    assert relative.median() <= 0.01
    with frozen(decoder), torch.no_grad():
        # exact: sdf runs the very forward pass sdf_and_jacobian does, on the same points in the same batch
        torch.testing.assert_close(fold_code(decoder, code, bf16=True).sdf(points), low_sdf, rtol=0, atol=0)


def test_decode_points_under_bf16_uses_the_bf16_fold():
    from ushape.decoder.query import decode_points

    decoder, code = float32_decoder_and_code()
    points = torch.rand(300, 3) * 2 - 1
    with frozen(decoder), torch.no_grad():
        expected = fold_code(decoder, code, bf16=True).sdf(points)
    # decode_points chunks the points, so its matrix products may round differently in the last fp32 bits;
    # bf16 and fp32 differ by ~1e-3 here, so 1e-6 still tells which fold ran.
    torch.testing.assert_close(decode_points(decoder, code, points, bf16=True), expected, rtol=0, atol=1e-6)
    assert (decode_points(decoder, code, points) - expected).abs().max() > 1e-5
