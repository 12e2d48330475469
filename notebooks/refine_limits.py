"""What bounds refinement on masks: the start, the rays, the steps or the prior? Probes on a real-shape model.

    PYTHONPATH=. python notebooks/refine_limits.py MODEL OUT.jsonl [--world W] [--shapes 10] [--views 6]
        [--variants shipped own_start rays64 steps40 sigma025]
    PYTHONPATH=. python notebooks/refine_limits.py --summary OUT.jsonl

MODEL as notebooks/pretrained_measure.py takes it. For each of the first test shapes, the fused code of n views
(spread around the orbit, true cameras) is refined on their masks as `reconstruct.py --refine masks` does
(`shipped`: 32 rays a side, 15 LM steps, sigma_mask 0.5) and under one change at a time:
- `own_start`: the same LM started from the shape's own code (the prior stays the fused Gaussian): does the
  objective keep the right answer where it is given it? Its energy at the own code is kept beside the
  shipped MAP's.
- `rays64`: 64 rays a side; `steps40`: 40 LM steps; `sigma025`: sigma_mask 0.25 (the masks weigh 4x against
  the prior).
- `pop_corr`, `pop_product`: the prior given the training codes' correlations (`with_population`).
Each result is scored against R2N2's 32^3 voxels (+0.4 voxel, as pretrained_measure.py), with the refinement's
record (energies at the start and end, steps) and the prior's part of the energy at the result and at the
own code (0.5 Mahalanobis^2 under the fused Gaussian; the rest of an energy is the masks'). Resumable.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pose_measure import iou as voxels_iou  # noqa: E402
from pretrained_measure import codes_dir, spread  # noqa: E402
from r2n2_ceiling import shape_frame  # noqa: E402

from ushape.data.layout import WorldIndex  # noqa: E402
from ushape.data.real.r2n2_voxels import read_r2n2_voxels  # noqa: E402
from ushape.decoder.artifacts import codes_file, load_codes  # noqa: E402
from ushape.decoder.query import frozen  # noqa: E402
from ushape.encoder.datamodule import view_files  # noqa: E402
from ushape.reconstruction.calibrated_fusion import default_fusion  # noqa: E402
from ushape.reconstruction.pretrained import open_model  # noqa: E402
from ushape.reconstruction.refine_calibration import read_refinement_calibration  # noqa: E402
from ushape.refinement import refine, refine_settings, world_views  # noqa: E402
from ushape.refinement.posterior import levenberg_marquardt, prior_precision  # noqa: E402
from ushape.refinement.views import screen_view  # noqa: E402

VARIANTS = ("shipped", "own_start", "rays64", "steps40", "sigma025", "pop_corr", "pop_product")
SHRINK = 0.1  # the training codes' correlation is shrunk this far towards the identity (conditioning)


def population(train_codes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean [D] and covariance [D, D] (float64, shrunk towards its diagonal) of the training codes [N, D]."""
    codes = train_codes.double()
    cov = torch.cov(codes.T)
    diag = torch.diag(torch.diagonal(cov))
    return codes.mean(0), (1 - SHRINK) * cov + SHRINK * diag


def with_population(variant: str, mu, var, pop_mu, pop_cov) -> tuple[torch.Tensor, torch.Tensor]:
    """The prior a population variant refines under, as (mean [D], covariance [D, D]):
    - `pop_corr`: the fused Gaussian's own variances, correlated as the training codes are (the encoder's
      diagonal says how far each coordinate may move, the population which moves go together);
    - `pop_product`: the fused Gaussian times the training codes' Gaussian (counts the population twice,
      since the encoder learned from it: an upper bound on what a tighter prior does)."""
    var = var.double()
    if variant == "pop_corr":
        std = torch.sqrt(torch.diagonal(pop_cov))
        corr = pop_cov / (std[:, None] * std[None, :])
        root = var.sqrt()
        return mu, root[:, None] * corr * root[None, :]
    precision = torch.diag(1.0 / var) + torch.linalg.inv(pop_cov)
    cov = torch.linalg.inv(precision)
    cov = 0.5 * (cov + cov.T)
    mean = cov @ (mu.double() / var + torch.linalg.solve(pop_cov, pop_mu))
    return mean.float(), cov


def settings(variant: str, scale: float):
    """The refinement's settings for a variant (reconstruct.py's for `shipped` and `own_start`)."""
    knobs = {"rays64": {"size": 64}, "steps40": {"iterations": 40}, "sigma025": {"sigma_mask": 0.25}}
    return refine_settings("masks", **{"size": 32, "information_scale": scale, **knobs.get(variant, {})})


def from_own_code(decoder, fused, truth, views, options) -> tuple[torch.Tensor, tuple[float, float]]:
    """The LM of `refine` (prior: the fused Gaussian) started from the shape's own code: (code, energies at the
    own code and at the end)."""
    usable = [s.view for s in (screen_view(v, False) for v in views) if s.view is not None]
    with frozen(decoder):
        z, _, _, energies, _ = levenberg_marquardt(
            decoder, fused.mu.double(), truth.double(), prior_precision(fused.var), usable, options,
            options.observation, False,
        )  # fmt: skip
    return z.float(), energies


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", nargs="?")
    parser.add_argument("out", nargs="?", type=Path)
    parser.add_argument("--world", default=None)
    parser.add_argument("--shapes", type=int, default=10)
    parser.add_argument("--views", type=int, default=6)
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    parser.add_argument("--summary", type=Path, default=None)
    args = parser.parse_args()
    if args.summary is not None:
        rows = [json.loads(line) for line in args.summary.read_text().splitlines() if line.strip()]
        for variant in VARIANTS:
            part = [r for r in rows if r["variant"] == variant]
            if part:
                iou = np.array([r["iou"] for r in part])
                base = np.array([r["fused_iou"] for r in part])
                own = np.array([r["own_iou"] for r in part])
                print(f"{variant:10s} {len(part):3d} shapes: fused {base.mean():.3f} -> {iou.mean():.3f} "
                      f"(own code {own.mean():.3f}), {np.mean([r['seconds'] for r in part]):.1f} s")  # fmt: skip
        return
    predictor = open_model(args.model, temperature=True)
    world = WorldIndex.load(args.world or predictor.world)
    codes = load_codes(codes_dir(predictor, None) / codes_file("test"))
    pop_mu, pop_cov = population(load_codes(codes_dir(predictor, None) / codes_file("train")).codes)
    fit = read_refinement_calibration(predictor.checkpoint, "masks")
    scale = fit["information_scale"] if fit else 1.0
    fusion = default_fusion(predictor)
    done = set()
    if args.out.is_file():
        done = {(r["shape"], r["variant"]) for r in map(json.loads, args.out.read_text().splitlines()) if r}
    decoder = predictor.decoder
    for shape_id in world.shape_ids("test")[: args.shapes]:
        todo = [v for v in args.variants if (shape_id, v) not in done]
        if not todo:
            continue
        files = view_files(world.root, shape_id)
        chosen = spread(args.views, len(files))
        images, _, _ = predictor.load_images([files[i] for i in chosen])
        mu, var = predictor.encode(images)
        fused = fusion(mu, var)
        truth = codes.lookup(shape_id)
        centre, scale_r2n2, side, source = shape_frame(world, shape_id)
        iou = partial(voxels_iou, decoder, voxels=read_r2n2_voxels(source)[0], frame=(centre, scale_r2n2, side))

        def prior_term(code) -> float:  # 0.5 (z - mu)^T Sigma^-1 (z - mu) of the fused prior
            dz = (code - fused.mu).double()
            return float(0.5 * dz @ prior_precision(fused.var) @ dz)

        views = world_views(world.views_path(shape_id), chosen)
        base = {"shape": shape_id, "views": args.views, "fused_iou": iou(fused.mu), "own_iou": iou(truth)}
        base["own_prior_term"] = prior_term(truth)
        for variant in todo:
            options = settings(variant, scale)
            started = time.perf_counter()
            if variant == "own_start":
                code, (e_own, e_end) = from_own_code(decoder, fused, truth, views, options)
                record = {"energy_start": e_own, "energy_end": e_end}
            elif variant.startswith("pop_"):
                post = refine(decoder, *with_population(variant, fused.mu, fused.var, pop_mu, pop_cov), views, options)
                code, record = post.mu, post.record()
            else:
                post = refine(decoder, fused.mu, fused.var, views, options)
                code, record = post.mu, post.record()
            row = {**base, "variant": variant, "iou": iou(code), "seconds": time.perf_counter() - started}
            row["prior_term"] = prior_term(code)
            row["record"] = {k: v for k, v in record.items() if isinstance(v, int | float | str | None)}
            with args.out.open("a") as f:
                f.write(json.dumps(row) + "\n")
            print(f"{shape_id} {variant:10s} fused {base['fused_iou']:.3f} own {base['own_iou']:.3f} -> "
                  f"{row['iou']:.3f} ({row['seconds']:.1f} s)", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
