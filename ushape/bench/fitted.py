"""Bench decoders with a real surface: an architecture's random weights briefly fitted to one procedural chair.

A random-weight decoder has surface everywhere, so coarse-to-fine extraction, the narrow band and
vertex counts say nothing about a trained one. A few hundred Adam steps on DeepSDF-style samples of
`generate_shape("chairs", 0)` (L1 on SDFs clamped to 0.1, one fixed code) give a field with one
chair-shaped zero level set and trained-like magnitudes away from it. The fitted weights are cached
(written atomically) under the bench's output folder, keyed by architecture, steps and seed.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from torch import nn

from ushape import atomic
from ushape.data.sampling import sample_sdf
from ushape.shapes import generate_shape

CLAMP = 0.1  # DeepSDF's clamping distance


def chair_samples(seed: int, n_points: int = 200_000) -> tuple[torch.Tensor, torch.Tensor]:
    """(points [P, 3], sdf [P]) of procedural chair `seed`, sampled as DeepSDF samples a mesh."""
    shape = generate_shape("chairs", seed)
    samples = sample_sdf(shape, shape.mesh(128), n_points, np.random.default_rng(seed))
    rows = torch.as_tensor(np.concatenate([samples["pos"], samples["neg"]]))
    return rows[:, :3].contiguous(), rows[:, 3].contiguous()


def fit_decoder(
    decoder: nn.Module, code: torch.Tensor, steps: int, seed: int = 0, batch: int = 8192, lr: float = 1e-3
) -> float:
    """Fit the decoder's weights (code fixed) to chair `seed` for `steps` Adam steps; returns the last L1 loss."""
    points, sdf = chair_samples(seed)
    generator = torch.Generator().manual_seed(seed)
    decoder.train().requires_grad_(True)
    dropout = getattr(decoder, "dropout", 0.0)
    if hasattr(decoder, "dropout"):
        decoder.dropout = 0.0  # a quick fit, not a regularised one
    optimizer = torch.optim.Adam(decoder.parameters(), lr=lr)
    target = sdf.clamp(-CLAMP, CLAMP)
    loss = torch.tensor(float("nan"))
    for _ in range(steps):
        pick = torch.randint(0, points.shape[0], (batch,), generator=generator)
        loss = (decoder(points[pick], code).clamp(-CLAMP, CLAMP) - target[pick]).abs().mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
    if hasattr(decoder, "dropout"):
        decoder.dropout = dropout
    decoder.eval().requires_grad_(False)
    return float(loss.detach())


def fitted_decoder(
    config: DictConfig, code: torch.Tensor, steps: int, cache_dir: Path | None, seed: int = 0
) -> tuple[nn.Module, str]:
    """(decoder of `config` fitted to chair `seed` for `steps` steps, provenance), from the cache when there."""
    torch.manual_seed(seed)
    decoder = instantiate(config)
    key = hashlib.sha256(json.dumps([OmegaConf.to_container(config), steps, seed, code.tolist()]).encode())
    path = None if cache_dir is None else Path(cache_dir) / f"fitted-{key.hexdigest()[:12]}.pt"
    if path is not None and path.is_file():
        decoder.load_state_dict(torch.load(path, weights_only=True))
        decoder.eval().requires_grad_(False)
        return decoder, f"fitted to procedural chair {seed} for {steps} steps (cached {path.name})"
    loss = fit_decoder(decoder, code, steps, seed)
    if path is not None:
        atomic.torch_save(decoder.state_dict(), path)
    return decoder, f"fitted to procedural chair {seed} for {steps} steps (L1 {loss:.4f})"
