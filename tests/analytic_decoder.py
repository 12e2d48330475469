"""A decoder with a known answer: the SDF of an ellipsoid whose x semi-axis the code sets.

A test double: drop-in for DeepSDFDecoder wherever a pipeline needs checking against exact
geometry; `sdf(xyz, z)` broadcasts the same way, and `save_decoder` / `load_decoder` rebuild it from
`{"_target_": "analytic_decoder.EllipsoidDecoder", ...}` wherever tests/ is importable.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


def ellipsoid_sdf(xyz: Tensor, a: Tensor, b: float) -> Tensor:
    """Signed distance-like field of the ellipsoid with semi-axes (a, b, b). xyz [..., 3], a [...] -> [...]

    The sign is exact; the magnitude is the normalised radius scaled by the shorter axis, exact on a
    sphere (a = b) and within a factor max(a, b)/min(a, b) of the true distance otherwise.
    """
    scale = torch.stack(torch.broadcast_tensors(a, torch.full_like(a, b), torch.full_like(a, b)), -1)
    return ((xyz / scale).norm(dim=-1) - 1) * torch.minimum(a, torch.full_like(a, b))


class EllipsoidDecoder(nn.Module):
    """sdf(xyz, z) of the ellipsoid (a, b, b) with a = base + spread * tanh(z_0); other code dims unused."""

    def __init__(self, latent_size: int = 3, b: float = 0.5, base: float = 0.5, spread: float = 0.3) -> None:
        super().__init__()
        self.latent_size, self.b, self.base, self.spread = latent_size, b, base, spread

    def forward(self, xyz: Tensor, z: Tensor) -> Tensor:
        a = self.base + self.spread * torch.tanh(z[..., 0])
        lead = torch.broadcast_shapes(xyz.shape[:-1], a.shape)
        return ellipsoid_sdf(xyz, a.expand(lead), self.b)
