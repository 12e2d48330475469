"""One code folded into a trained DeepSDF decoder: plain-tensor inference and latent Jacobians without autograd.

Decoding a whole grid or a mesh's vertices always uses one code z for every point. Folding it in
once (z's columns of the first and the latent_in layers become part of their biases; weight
normalisation becomes plain weights) leaves an MLP on xyz alone. Its forward does no concatenation
and multiplies 3 input columns where the module multiplies D + 3. Its hand-written backward gives
ds/dz at every point from the activations the forward kept: one matrix product per layer, the
same count as the forward, with none of autograd's per-point copy of z, graph or concat backward.

With s = tanh(a_L), a_i = W_i h_i + b_i, h_{i+1} = relu(a_i), and h_i = [h_i', z, x] at a latent_in
layer, the chain rule gives g_L = 1 - s^2, g_{i-1} = (g_i W_i^h) * [a_{i-1} > 0], and
ds/dz = sum over the layers that read z (the first and the latent_in ones) of g_i W_i^z.

Folded in bf16 (`fold_code(..., bf16=True)`), the products of hidden features and of the backward's
gradients run in bf16 (what AMX and bf16 tensor cores multiply natively), while the point's own
columns (x W_x^T), the biases, the last layer and the accumulated ds/dz stay float32: the point is
never rounded to bf16 (autocast rounds it by up to 2e-3 in [-1, 1], which moves thin parts of a
mesh by as much).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from ushape.decoder.network import DeepSDFDecoder


@dataclass(frozen=True)
class FoldedLayer:
    """a = h' W_h^T + x W_x^T + bias (bias holds b + W_z z); W_z kept for the Jacobian."""

    hidden: Tensor | None  # [out, k] weights on the previous layer's features (None: first layer)
    xyz: Tensor | None  # [out, 3] weights on the point (None: a layer that does not read the input)
    code: Tensor | None  # [out, D] weights on the code
    bias: Tensor  # [out] with the code's contribution folded in


@dataclass(frozen=True)
class FoldedDecoder:
    """A DeepSDFDecoder at one code: SDF and ds/dz at points [P, 3] (the decoder's dtype), no autograd."""

    layers: tuple[FoldedLayer, ...]
    output_tanh: bool
    low: torch.dtype | None = None  # dtype of the hidden layers' products (bf16), None: the weights' own

    def sdf(self, points: Tensor) -> Tensor:  # [P, 3] -> [P]
        """f(x, z) at every point, as the decoder module computes it in eval mode."""
        value, _ = self._forward(points, keep=False)
        return value

    def sdf_and_jacobian(self, points: Tensor) -> tuple[Tensor, Tensor]:  # [P, 3] -> ([P], [P, D])
        """f(x, z) [P] and ds/dz [P, D] at every point: one forward and one hand-written backward."""
        value, jacobian, _ = self.sdf_and_gradients(points, with_xyz=False)
        return value, jacobian

    def sdf_and_gradients(self, points: Tensor, with_xyz: bool = True) -> tuple[Tensor, Tensor, Tensor | None]:
        """f(x, z) [P], ds/dz [P, D] and (with_xyz) ds/dx [P, 3] from the same backward pass."""
        value, hidden = self._forward(points, keep=True)
        grad = (1.0 - value.square()).unsqueeze(-1) if self.output_tanh else torch.ones_like(value).unsqueeze(-1)
        jacobian, spatial = None, None
        for i in range(len(self.layers) - 1, -1, -1):
            layer = self.layers[i]
            if layer.code is not None:
                term = (grad.to(layer.code.dtype) @ layer.code).to(value.dtype)  # [P, D]
                jacobian = term if jacobian is None else jacobian.add_(term)
            if with_xyz and layer.xyz is not None:
                term = grad.to(layer.xyz.dtype) @ layer.xyz  # [P, 3]
                spatial = term if spatial is None else spatial.add_(term)
            if i == 0:
                break
            # relu'(a_{i-1}): h_i = relu(a_{i-1}) is > 0 exactly there. ReLU's own backward kernel is
            # one fused pass; multiplying by a bool mask measured 20-30x slower on CPU.
            back = grad.to(layer.hidden.dtype) @ layer.hidden
            grad = torch.ops.aten.threshold_backward(back.to(hidden[i - 1].dtype), hidden[i - 1], 0.0)  # [P, k]
        return value, jacobian, spatial

    def multiply_adds(self) -> tuple[int, int]:
        """Multiply-adds per point of `sdf` and of the backward `sdf_and_jacobian` adds to it.

        Their ratio plus one is the arithmetic floor of the linearised field's cost over the plain field's.
        """
        forward = backward = 0
        for i, layer in enumerate(self.layers):
            out = layer.bias.shape[0]
            forward += out * sum(w.shape[1] for w in (layer.hidden, layer.xyz) if w is not None)
            backward += out * (layer.code.shape[1] if layer.code is not None else 0)
            backward += out * layer.hidden.shape[1] if i > 0 else 0
        return forward, backward

    def _forward(self, points: Tensor, keep: bool) -> tuple[Tensor, list[Tensor]]:
        kept: list[Tensor] = []
        x = None
        last = len(self.layers) - 1
        for i, layer in enumerate(self.layers):
            if x is None:
                a = torch.addmm(layer.bias, points, layer.xyz.T)
            elif self.low is None:
                a = torch.addmm(layer.bias, x, layer.hidden.T)
                if layer.xyz is not None:
                    a.addmm_(points, layer.xyz.T)
            else:
                a = self._low_layer(layer, x, points)
            if i < last:
                x = torch.relu_(a) if self.low is None else torch.relu_(a).to(self.low)
                if keep:
                    kept.append(x)
            else:
                x = a
        value = x.squeeze(-1)
        return (torch.tanh(value) if self.output_tanh else value), kept

    @staticmethod
    def _low_layer(layer: FoldedLayer, x: Tensor, points: Tensor) -> Tensor:  # x [P, k] in bf16 -> a [P, out]
        """A hidden layer's pre-activation with x in bf16: in bf16, but float32 where it reads the point."""
        if layer.xyz is None and layer.hidden.dtype == x.dtype:
            return torch.addmm(layer.bias.to(x.dtype), x, layer.hidden.T)
        a = layer.bias if layer.xyz is None else torch.addmm(layer.bias, points, layer.xyz.T)
        return a + (x.to(layer.hidden.dtype) @ layer.hidden.T).to(a.dtype)


def fold_code(decoder: nn.Module, code: Tensor, bf16: bool = False) -> FoldedDecoder | None:
    """The decoder at code [D] as a FoldedDecoder, or None where it cannot be folded (then use the module).

    Folds only a DeepSDFDecoder in eval mode (or without dropout), in the decoder's dtype and on its
    device; call it inside `frozen(decoder)` so weight normalisation is computed once. With bf16 the
    weights on hidden features and on the code are kept in bf16 (see the module's doc).
    """
    if not isinstance(decoder, DeepSDFDecoder) or type(decoder).forward is not DeepSDFDecoder.forward:
        return None  # another network, or a subclass that computes something else
    if decoder.training and decoder.dropout > 0:
        return None
    if code.ndim != 1 or code.shape[0] != decoder.latent_size:
        raise ValueError(f"code must be [{decoder.latent_size}] for this decoder, got {tuple(code.shape)}")
    z = code.detach().to(decoder.layers[0].bias)
    d = z.shape[0]
    layers = []
    with torch.no_grad():
        for i, module in enumerate(decoder.layers):
            weight, bias = module.weight.detach(), module.bias.detach()
            if i == 0:  # input [z, x]
                layers.append(
                    FoldedLayer(None, weight[:, d:].contiguous(), weight[:, :d].contiguous(), bias + weight[:, :d] @ z)
                )
            elif i in decoder.latent_in:  # input [h', z, x]
                k = weight.shape[1] - d - 3
                code_w = weight[:, k : k + d].contiguous()
                layers.append(
                    FoldedLayer(weight[:, :k].contiguous(), weight[:, k + d :].contiguous(), code_w, bias + code_w @ z)
                )
            else:
                layers.append(FoldedLayer(weight.contiguous(), None, None, bias.clone()))
    if not bf16:
        return FoldedDecoder(tuple(layers), decoder.output_tanh)
    # The last layer (a few outputs) stays float32: its output is the SDF, which bf16 would round.
    low = tuple(_in_bf16(layer) for layer in layers[:-1]) + tuple(layers[-1:])
    return FoldedDecoder(low, decoder.output_tanh, torch.bfloat16)


def _in_bf16(layer: FoldedLayer) -> FoldedLayer:
    """The layer with its weights on hidden features and on the code in bf16 (the point's and the bias as they are)."""
    low = [None if w is None else w.to(torch.bfloat16) for w in (layer.hidden, layer.code)]
    return FoldedLayer(low[0], layer.xyz, low[1], layer.bias)
