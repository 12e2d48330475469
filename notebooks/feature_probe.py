"""Do the frozen backbone's features lose the shape by pooling it away? A ridge probe on a real-shape model.

    PYTHONPATH=. python notebooks/feature_probe.py MODEL WORLD OUT.json [--train 300] [--val 100]

MODEL as notebooks/pretrained_measure.py takes it. Its frozen EfficientNet-Lite0 reads the training shapes'
12 renders and the val shapes' views 0 and 6 (the model's own input preparation), and two feature sets are
taken in one pass: `stages` (every stage's spatial mean and the head's, what the shipped heads read) and
`grid2` (the same maps averaged over each quarter of the image, 4x as many: where the parts are, not only
what they are). A ridge regression from each (standardised) to the model's training codes is fitted on the
training views and scored on the val views: latent L2 against the val shapes' own codes, and IoU against
R2N2's voxels at +0.4 voxel (as pretrained_measure.py), beside the model's own heads on the same views and the
mean training code (the image ignored). `--size S`: the backbone reads the images resized to S px (bilinear)
instead of the model's own size (ImageNet's networks were trained at 224 px; the shipped heads read 128).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pose_measure import iou  # noqa: E402
from pretrained_measure import codes_dir  # noqa: E402
from r2n2_ceiling import shape_frame  # noqa: E402

from ushape.data.layout import WorldIndex  # noqa: E402
from ushape.data.real.r2n2_voxels import read_r2n2_voxels  # noqa: E402
from ushape.decoder.artifacts import codes_file, load_codes  # noqa: E402
from ushape.encoder.datamodule import view_files  # noqa: E402
from ushape.reconstruction.pretrained import open_model  # noqa: E402

LAMBDAS = (1e2, 1e3, 1e4, 1e5)


@torch.no_grad()
def two_poolings(encoder, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """images [B, 3, S, S] in [0, 1] -> (stage means [B, F], stage 2x2-grid means [B, 4F])."""
    maps = encoder.backbone.stage_maps((images - encoder.pixel_mean) / encoder.pixel_std)
    means = torch.cat([m.mean(dim=(-2, -1)) for m in maps], dim=1)
    grids = torch.cat([F.adaptive_avg_pool2d(m, 2).flatten(1) for m in maps], dim=1)
    return means, grids


def ridge(x: np.ndarray, y: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """Weights [F, D] and bias [D] of ridge regression on standardised x (the caller standardises)."""
    mean = y.mean(0)
    w = np.linalg.solve(x.T @ x + lam * np.eye(x.shape[1]), x.T @ (y - mean))
    return w, mean


def probe_parser(doc: str) -> argparse.ArgumentParser:
    """The arguments the feature probes share: MODEL WORLD OUT.json, --train and --val shapes."""
    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model")
    parser.add_argument("world")
    parser.add_argument("out", type=Path)
    parser.add_argument("--train", type=int, default=300)
    parser.add_argument("--val", type=int, default=100)
    return parser


def views_iou(predictor, world: WorldIndex, ids: list[str], views: int = 2):
    """A scorer: codes [len(ids) * views, D] (each shape's views in turn) -> mean IoU against R2N2's voxels."""
    frames = {s: shape_frame(world, s) for s in ids}
    voxels = {s: read_r2n2_voxels(frames[s][3])[0] for s in ids}

    def mean_iou(codes) -> float:
        pairs = zip(codes, np.repeat(ids, views))
        scores = [
            iou(predictor.decoder, torch.as_tensor(c, dtype=torch.float32), voxels[s], frames[s][:3]) for c, s in pairs
        ]
        return float(np.mean(scores))

    return mean_iou


def main() -> None:
    parser = probe_parser(__doc__)
    parser.add_argument("--size", type=int, default=None, help="backbone input size (default: the model's)")
    args = parser.parse_args()
    started = time.time()
    predictor = open_model(args.model, temperature=True)
    encoder = predictor.model.encoder.eval()
    world = WorldIndex.load(args.world)
    folder = codes_dir(predictor, None)
    train_codes, val_codes = load_codes(folder / codes_file("train")), load_codes(folder / codes_file("val"))

    def read(ids: list[str], views: list[int] | None):
        feats, codes, heads = {"stages": [], "grid2": []}, [], []
        for shape_id in ids:
            files = view_files(world.root, shape_id)
            images, _, _ = predictor.load_images([files[v] for v in views] if views else files)
            sized = images if args.size is None else F.interpolate(images, size=args.size, mode="bilinear")
            means, grids = two_poolings(encoder, sized)
            feats["stages"].append(means.numpy())
            feats["grid2"].append(grids.numpy())
            codes += [np.asarray(train_codes.lookup(shape_id) if views is None else val_codes.lookup(shape_id))] * len(
                images
            )
            if views is not None:
                heads.append(predictor.encode(images)[0].detach().numpy())
        return {k: np.concatenate(v) for k, v in feats.items()}, np.stack(codes), heads

    train_ids = world.shape_ids("train")[: args.train]
    val_ids = world.shape_ids("val")[: args.val]
    x_train, y_train, _ = read(train_ids, None)
    x_val, y_val, heads = read(val_ids, [0, 6])
    mean_iou = views_iou(predictor, world, val_ids)

    heads = np.concatenate(heads)
    report = {"train_views": len(y_train), "val_views": len(y_val), "heads": {}, "ridge": {}}
    report["heads"] = {"latent_l2": float(np.linalg.norm(heads - y_val, axis=1).mean()), "iou": mean_iou(heads)}
    print("heads", report["heads"], flush=True)
    mean_code = np.repeat(y_train.mean(0, keepdims=True), len(y_val), axis=0)
    report["mean_code"] = {
        "latent_l2": float(np.linalg.norm(mean_code - y_val, axis=1).mean()),
        "iou": mean_iou(mean_code),
    }
    print("mean training code", report["mean_code"], flush=True)
    for name, x in x_train.items():
        mu, sd = x.mean(0), x.std(0) + 1e-6
        xt, xv = (x - mu) / sd, (x_val[name] - mu) / sd
        rows = {}
        for lam in LAMBDAS:
            w, bias = ridge(xt, y_train, lam)
            pred = xv @ w + bias
            rows[lam] = {"latent_l2": float(np.linalg.norm(pred - y_val, axis=1).mean()), "pred": pred}
        best = min(rows, key=lambda k: rows[k]["latent_l2"])
        report["ridge"][name] = {
            "features": x.shape[1],
            "latent_l2_by_lambda": {str(k): v["latent_l2"] for k, v in rows.items()},
            "lambda": best,
            "iou": mean_iou(rows[best]["pred"]),
        }
        print(name, {k: v for k, v in report["ridge"][name].items()}, flush=True)
    report["seconds"] = round(time.time() - started, 1)
    args.out.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
