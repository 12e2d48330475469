"""Codes of unseen shapes with the decoder frozen (DeepSDF's reconstruct.py), many shapes at once.

Per shape and iteration, as DeepSDF: draw `samples_per_iter` SDF samples (half sdf >= 0, half
sdf < 0), minimise mean clamped L1 + code_reg * mean(z^2) with Adam, start from N(0, init_std^2),
divide the learning rate by 10 at `lr_drop_at`. Shapes are independent: the batch loss is the sum
of per-shape losses, so each code gets the gradient it would get alone.
"""

from __future__ import annotations

from typing import Sequence

import torch
from torch import Tensor, nn

from ushape.data.sdf_dataset import SDFSamplesDataset
from ushape.decoder.losses import code_prior
from ushape.decoder.precision import training_bf16
from ushape.decoder.query import decoder_autocast, decoder_device, frozen

SampleSource = Sequence[tuple[Tensor, Tensor]] | SDFSamplesDataset

# Sample rows a decoder pass takes at most. On the 2-core AMD EPYC (AVX2), 20 quickstart codes x 2,000
# samples: 5.8 s a code in one 40,000-row pass, 4.0 s in passes of 16,384 rows, 2.9 s in passes of 8,192
# (a 256-wide layer's activations for 40,000 rows, 41 MB, do not stay in cache); docs/benchmark.md.
ROWS_PER_PASS = 8_192


def optimise_codes(
    decoder: nn.Module,
    sdf_samples: SampleSource,
    iterations: int = 800,
    lr: float = 5e-3,
    lr_drop_at: int = 400,
    samples_per_iter: int = 8000,
    code_reg: float = 1e-4,
    clamp: float = 0.1,
    init_std: float = 0.01,
    bf16: bool | str = False,
    seed: int = 0,
    rows_per_pass: int = ROWS_PER_PASS,
) -> Tensor:
    """Latent codes fitting each shape's SDF samples under the frozen decoder. -> [S, D]

    sdf_samples: a list of (xyz [N, 3], sdf [N]) per shape, or an SDFSamplesDataset (all its samples).
    bf16: autocast the decoder to bf16 (True), not (False), or where it is faster on its device ("auto").
    rows_per_pass: at most this many sample rows (shapes x samples_per_iter) go through the decoder at once;
    more shapes are split into passes whose gradients add up before the one Adam step (each code's gradient
    comes from its own pass, so the result is the same up to float rounding; only the speed changes).
    """
    pos, pos_count, neg, neg_count = _padded_by_sign(sdf_samples)
    device = decoder_device(decoder)
    bf16 = training_bf16(bf16, device)
    pos, pos_count, neg, neg_count = (t.to(device) for t in (pos, pos_count, neg, neg_count))
    generator = torch.Generator(device="cpu").manual_seed(seed)
    num_shapes, latent_size = pos.shape[0], decoder.latent_size
    codes = (torch.randn(num_shapes, latent_size, generator=generator) * init_std).to(device).requires_grad_(True)
    optimiser = torch.optim.Adam([codes], lr=lr)
    n_pos = samples_per_iter - samples_per_iter // 2
    shapes_per_pass = max(1, rows_per_pass // samples_per_iter)
    with frozen(decoder):
        for step in range(iterations):
            if step == lr_drop_at:
                for group in optimiser.param_groups:
                    group["lr"] = lr / 10
            rows = torch.cat(
                [  # [S, K, 4]
                    _draw(pos, pos_count, n_pos, generator),
                    _draw(neg, neg_count, samples_per_iter - n_pos, generator),
                ],
                dim=1,
            )
            optimiser.zero_grad(set_to_none=True)
            for start in range(0, num_shapes, shapes_per_pass):
                part = slice(start, start + shapes_per_pass)  # views, not gathered copies
                with decoder_autocast(device, bf16):
                    pred = decoder(rows[part, :, :3], codes[part, None, :])  # [s, K]
                target = rows[part, :, 3].clamp(-clamp, clamp)
                fit = (pred.float().clamp(-clamp, clamp) - target).abs().mean(dim=1)
                (fit + code_prior(codes[part], code_reg)).sum().backward()
            optimiser.step()
    return codes.detach().cpu()


def _padded_by_sign(source: SampleSource) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Per-shape samples split by sign, zero-padded: (pos [S, P, 4], counts [S], neg [S, Q, 4], counts [S])."""
    if isinstance(source, SDFSamplesDataset):
        pairs = [source.samples(i) for i in range(len(source))]
    else:
        pairs = [_split_by_sign(xyz, sdf, i) for i, (xyz, sdf) in enumerate(source)]
    if not pairs:
        raise ValueError("no shapes given to optimise codes for")
    pos = nn.utils.rnn.pad_sequence([p for p, _ in pairs], batch_first=True)
    neg = nn.utils.rnn.pad_sequence([n for _, n in pairs], batch_first=True)
    counts = [torch.tensor([len(t) for t in side]) for side in zip(*pairs)]
    return pos, counts[0], neg, counts[1]


def _split_by_sign(xyz: Tensor, sdf: Tensor, index: int) -> tuple[Tensor, Tensor]:
    """(rows with sdf >= 0, rows with sdf < 0), rows (x, y, z, sdf) [N, 4]."""
    xyz, sdf = torch.as_tensor(xyz, dtype=torch.float32), torch.as_tensor(sdf, dtype=torch.float32).reshape(-1)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or xyz.shape[0] != sdf.shape[0]:
        raise ValueError(
            f"shape {index}: expected xyz [N, 3] and sdf [N], got {tuple(xyz.shape)} and {tuple(sdf.shape)}"
        )
    rows = torch.cat([xyz, sdf[:, None]], dim=1)
    pos, neg = rows[sdf >= 0], rows[sdf < 0]
    if len(pos) == 0 or len(neg) == 0:
        raise ValueError(f"shape {index}: needs samples both outside (sdf >= 0) and inside (sdf < 0) the surface")
    return pos, neg


def _draw(padded: Tensor, counts: Tensor, k: int, generator: torch.Generator) -> Tensor:
    """k rows per shape drawn with replacement from its first counts[s] rows. [S, P, 4] -> [S, k, 4]"""
    u = torch.rand(padded.shape[0], k, generator=generator).to(padded.device)
    idx = (u * counts[:, None]).long().clamp(max=padded.shape[1] - 1)
    return torch.gather(padded, 1, idx[..., None].expand(-1, -1, padded.shape[2]))
