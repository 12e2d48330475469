"""A decoder with a known answer: the SDF of an ellipsoid whose x semi-axis the code sets.

A test double: drop-in for DeepSDFDecoder wherever a pipeline needs checking against exact
geometry; `sdf(xyz, z)` broadcasts the same way, and `save_decoder` / `load_decoder` rebuild it from
`{"_target_": "analytic_decoder.EllipsoidDecoder", ...}` wherever tests/ is importable.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

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


def run_with_ellipsoid(tiny_run: dict, base: Path, latent_size: int) -> Path:
    """A copy of tiny_run's run under base whose encoder decodes through the analytic ellipsoid (a surface for
    every code): its decoder folder copied with decoder.pt replaced, the checkpoint and run.json pointed there."""
    from ushape import atomic
    from ushape.decoder.artifacts import DECODER_FILE, save_decoder

    decoder_dir = shutil.copytree(tiny_run["decoder_dir"], base / "decoder")
    config = {"_target_": "analytic_decoder.EllipsoidDecoder", "latent_size": latent_size}
    save_decoder(decoder_dir / DECODER_FILE, EllipsoidDecoder(latent_size=latent_size), config)
    run = shutil.copytree(tiny_run["run"], base / "run")
    checkpoint = run / "checkpoints" / "best.ckpt"
    blob = torch.load(checkpoint, map_location="cpu", weights_only=False)
    blob["hyper_parameters"]["decoder_path"] = str(decoder_dir)
    torch.save(blob, checkpoint)
    record = json.loads((run / "run.json").read_text())
    atomic.write_json(
        run / "run.json", {**record, "decoder_dir": str(decoder_dir), "encoder_checkpoint": str(checkpoint)}
    )
    return run
