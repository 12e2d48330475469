"""The paper's fusion comparisons (its Tables 1, 3 and 4) on a real-shape model: ES against FroDO* (L2) from one
view, and Bayesian-K against averaging over 10 views, clean and with every view cropped to a random area in
[min scale, 1].

    PYTHONPATH=. python notebooks/pretrained_fusion.py ES_MODEL L2_MODEL OUT.json [--world W] [--shapes 100]
        [--group 10] [--k 4] [--min-scales 1 0.1]

ES_MODEL / L2_MODEL: `pretrained:<name>` or run folders (the two heads trained on the same cached features).
Each test shape's first `group` views (our renders) are encoded by both, cropped as eval.py's corrupted protocol
crops them (the same seed per view), and every code is scored against R2N2's own 32^3 voxels at +0.4 voxel
(as notebooks/pretrained_measure.py): IoU. Where the shape's own code is known (its latent-optimised test code),
the latent energy score and NLL of the fused Gaussian against it are reported too (per dimension, mean).
Encodings are cached under OUT's folder; the scores are cheap (one 32^3 decoder pass per code).
"""

from __future__ import annotations

import argparse
import json
import sys
from functools import partial
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pose_measure import iou  # noqa: E402
from pretrained_measure import codes_dir  # noqa: E402
from r2n2_ceiling import shape_frame  # noqa: E402

from ushape.data.layout import WorldIndex  # noqa: E402
from ushape.data.real.r2n2_voxels import read_r2n2_voxels  # noqa: E402
from ushape.decoder.artifacts import codes_file, load_codes  # noqa: E402
from ushape.evaluation.views import ViewKey, encode_views  # noqa: E402
from ushape.fusion.rules import fuse_average, fuse_bayesian, fuse_bayesian_k  # noqa: E402
from ushape.metrics.scores import energy_score_1d, gaussian_nll_1d  # noqa: E402
from ushape.reconstruction.calibrated_fusion import default_fusion  # noqa: E402
from ushape.reconstruction.pretrained import open_model  # noqa: E402


def rules(predictor, k: int) -> dict:
    """The fusion rules compared: average, Bayesian-K, Bayesian (all views), and the model's shared rule."""
    out = {"average": fuse_average, f"bayesian-{k}": partial(fuse_bayesian_k, k=k), "bayesian": fuse_bayesian}
    shared = default_fusion(predictor)
    if type(shared).__name__ != "BayesianFusion":
        out["shared"] = shared
    return out


def latent_scores(mu: torch.Tensor, var: torch.Tensor, truth: torch.Tensor) -> dict:
    """Per-dimension mean energy score and NLL of N(mu, var) at the shape's own code."""
    var = var.clamp_min(1e-12)
    return {"es": float(energy_score_1d(mu, var, truth).mean()), "nll": float(gaussian_nll_1d(mu, var, truth).mean())}


def measure(args) -> dict:
    models = {"ES": open_model(args.es, temperature=True), "L2": open_model(args.l2)}
    world_root = args.world or models["ES"].world or models["L2"].world
    if world_root is None:
        raise SystemExit("error: neither model names its world (a shipped model has none): pass --world")
    world = WorldIndex.load(world_root)
    codes = load_codes(codes_dir(models["ES"], None) / codes_file("test"))
    shape_ids = world.shape_ids("test")[: args.shapes]
    keys = [ViewKey(s, v) for s in shape_ids for v in range(args.group)]
    cache = args.out.parent / "fusion_cache"
    frames = {}  # per shape: ((centre, scale, side), voxels), as pose_measure.iou takes them
    for s in shape_ids:
        centre, scale, side, source = shape_frame(world, s)
        frames[s] = ((centre, scale, side), read_r2n2_voxels(source)[0])
    rows = []
    for name, predictor in models.items():
        decoder = predictor.decoder
        # FroDO*'s L2 head predicts a code, not its uncertainty: its multi-view rule is the average.
        compared = rules(predictor, args.k) if name == "ES" else {"average": fuse_average}
        for min_scale in args.min_scales:
            enc = encode_views(predictor, world, keys, min_scale, args.seed, cache)
            mu = enc.mu.reshape(len(shape_ids), args.group, -1)
            var = enc.var.reshape(len(shape_ids), args.group, -1)
            for i, s in enumerate(shape_ids):
                frame, voxels = frames[s]
                truth = codes.lookup(s)
                row = {
                    "model": name,
                    "min_scale": min_scale,
                    "shape": s,
                    "single": iou(decoder, mu[i, 0], voxels, frame),
                }
                row["single_latent"] = latent_scores(mu[i, 0], var[i, 0], truth)
                for rule_name, rule in compared.items():
                    fused = rule(mu[i], var[i])
                    row[rule_name] = iou(decoder, fused.mu, voxels, frame)
                    row[f"{rule_name}_latent"] = latent_scores(fused.mu, fused.var, truth)
                rows.append(row)
            print(f"{name} min scale {min_scale:g}: {len(shape_ids)} shapes", flush=True)
    return {"world": str(world.root), "es": args.es, "l2": args.l2, "group": args.group, "k": args.k, "rows": rows}


def summary(result: dict) -> str:
    """The markdown tables: mean IoU (and latent ES) per model, crop and rule."""
    rows = result["rows"]
    rule_names = [k for k in rows[0] if k not in ("model", "min_scale", "shape") and not k.endswith("_latent")]
    lines = ["| model | min scale | " + " | ".join(rule_names) + " |", "|---|---|" + "---|" * len(rule_names)]
    for model in ("ES", "L2"):
        for scale in sorted({r["min_scale"] for r in rows}, reverse=True):
            part = [r for r in rows if r["model"] == model and r["min_scale"] == scale]
            cells = []
            for rule in rule_names:
                values = [r[rule] for r in part if rule in r]
                es = [r[f"{rule}_latent"]["es"] for r in part if f"{rule}_latent" in r]
                if not values:
                    cells.append("–")
                elif model == "L2":  # its variance is not a prediction: no latent score
                    cells.append(f"{np.mean(values):.3f}")
                else:
                    cells.append(f"{np.mean(values):.3f} (ES {np.mean(es):.3f})")
            lines.append(f"| {model} | {scale:g} | " + " | ".join(cells) + " |")
    k_rule = f"bayesian-{result['k']}"
    for scale in sorted({r["min_scale"] for r in rows}, reverse=True):
        es = {r["shape"]: r for r in rows if r["model"] == "ES" and r["min_scale"] == scale}
        l2 = {r["shape"]: r for r in rows if r["model"] == "L2" and r["min_scale"] == scale}
        pairs = {
            f"ES {k_rule} - ES average": [r[k_rule] - r["average"] for r in es.values()],
            f"ES {k_rule} - L2 average": [es[s][k_rule] - l2[s]["average"] for s in es if s in l2],
            "ES single - L2 single": [es[s]["single"] - l2[s]["single"] for s in es if s in l2],
        }
        for label, d in pairs.items():
            if d:
                d = np.asarray(d)
                lines.append(f"min scale {scale:g}, {label}: {d.mean():+.3f} +- {d.std(ddof=1) / np.sqrt(len(d)):.3f} "
                             f"(s.e.), higher on {100 * np.mean(d > 0):.0f} % of the shapes")  # fmt: skip
    shapes = len({r["shape"] for r in rows})
    lines.append(
        f"\n{shapes} test shapes, {result['group']} views each; IoU against R2N2's voxels at +0.4 voxel, mean; "
        "ES: latent energy score per dimension against the shape's own code (lower is better)."
    )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("es", nargs="?")
    parser.add_argument("l2", nargs="?")
    parser.add_argument("out", type=Path)
    parser.add_argument("--world", default=None)
    parser.add_argument("--shapes", type=int, default=100)
    parser.add_argument("--group", type=int, default=10)
    parser.add_argument("--k", type=int, default=4)
    parser.add_argument("--min-scales", type=float, nargs="+", default=[1.0, 0.1])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--summary", action="store_true", help="print the tables of a finished OUT.json")
    args = parser.parse_args()
    if not args.summary:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(measure(args)))
    print(summary(json.loads(args.out.read_text())))


if __name__ == "__main__":
    main()
