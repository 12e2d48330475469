"""Does a loss in SDF space lift the one-view code? A probe on a real-shape model's cached features.

    PYTHONPATH=. python notebooks/sdf_loss_probe.py MODEL WORLD OUT.json [--weights 0 30 100] [--val 100]

The heads learn the code in latent space (ES, NLL, L2), where every dimension counts alike; what is scored
is the shape the decoder draws from it. Here one Gaussian head of the model's size (hidden 512, dropout 0.3,
AdamW 1e-3, weight decay 0.05, poly decay, batch 128, 4 epochs: the shipped heads' recipe) is trained on the
model's cached training features (`<world>/features/train-*.pt`, the file the shipped heads read) with the
latent L2 loss plus `weight` x the clamped L1 between the decoder's SDF at the predicted code and the
shape's own SDF samples (`<world>/sdf/<id>.npz`, half inside, half outside, `--points` a view), the decoder
frozen. Each weight is scored on views 0 and 6 of the first `--val` val shapes (their cached clean features):
latent L2 against their own codes and IoU against R2N2's voxels at +0.4 voxel (notebooks/pretrained_measure.py's
protocol), beside the model's shipped heads on the same features.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from feature_probe import views_iou  # noqa: E402
from pretrained_measure import codes_dir  # noqa: E402

from ushape.data.layout import WorldIndex  # noqa: E402
from ushape.decoder.artifacts import codes_file, load_codes  # noqa: E402
from ushape.encoder.heads import GaussianHead  # noqa: E402
from ushape.reconstruction.pretrained import open_model  # noqa: E402

CLAMP = 0.1  # the decoder's training clamp (stage1.module.clamp_distance)


def feature_file(world: Path, split: str, views: int) -> dict:
    """The cached features of a split whose item count fits: train has 4 passes of 12 views, val 1."""
    for path in sorted((world / "features").glob(f"{split}-*.pt")):
        cached = torch.load(path, map_location="cpu", weights_only=False)
        if len(cached["items"]) % views == 0:
            return cached
    raise FileNotFoundError(f"no cached {split} features under {world / 'features'}: train the model's heads first")


def sdf_samples(world: WorldIndex, ids: list[str], per_side: int, seed: int = 0) -> dict[str, torch.Tensor]:
    """Each shape's SDF samples [2 * per_side, 4] (xyz, sdf): per_side drawn from inside and from outside."""
    rng = np.random.default_rng(seed)
    out = {}
    for shape_id in ids:
        data = np.load(world.root / "sdf" / f"{shape_id}.npz")
        parts = [data[k][rng.choice(len(data[k]), per_side, replace=len(data[k]) < per_side)] for k in ("pos", "neg")]
        out[shape_id] = torch.from_numpy(np.concatenate(parts)).float()
    return out


def train_head(x, y, shape_index, samples, decoder, weight, points, epochs=4, batch=128, seed=0) -> GaussianHead:
    """One head: features x [N, F] (standardised) -> codes y [N, D]; L2 + weight * clamped SDF L1."""
    torch.manual_seed(seed)
    head = GaussianHead(x.shape[1], y.shape[1], hidden=512, dropout=0.3)
    opt = torch.optim.AdamW(head.parameters(), lr=1e-3, weight_decay=0.05)
    steps = epochs * (len(x) // batch)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda k: max(0.0, 1 - k / steps) ** 0.9)
    per_shape = samples.shape[1]
    for _ in range(epochs):
        order = torch.randperm(len(x))
        for i in range(len(x) // batch):
            idx = order[i * batch : (i + 1) * batch]
            mu, _ = head(x[idx])
            loss = (mu - y[idx]).pow(2).sum(1).mean()
            if weight > 0:
                pick = torch.randint(per_shape, (len(idx), points))
                pts = samples[shape_index[idx]].gather(1, pick[..., None].expand(-1, -1, 4))
                pred = decoder(pts[..., :3], mu[:, None, :])  # [B, points]
                target = pts[..., 3].clamp(-CLAMP, CLAMP)
                loss = loss + weight * (pred.clamp(-CLAMP, CLAMP) - target).abs().mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
    return head.eval()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model")
    parser.add_argument("world", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--weights", type=float, nargs="+", default=[0.0, 30.0, 100.0])
    parser.add_argument("--points", type=int, default=256)
    parser.add_argument("--val", type=int, default=100)
    parser.add_argument("--epochs", type=int, default=4)
    args = parser.parse_args()
    started = time.time()
    predictor = open_model(args.model, temperature=True)
    encoder, decoder = predictor.model.encoder.eval(), predictor.decoder.eval().requires_grad_(False)
    world = WorldIndex.load(args.world)
    folder = codes_dir(predictor, None)
    train_codes, val_codes = load_codes(folder / codes_file("train")), load_codes(folder / codes_file("val"))

    train = feature_file(args.world, "train", 12)
    ids = sorted({s for s, _ in train["items"]})
    index = {s: i for i, s in enumerate(ids)}
    x = encoder.head_input(train["features"]).detach()
    y = torch.stack([torch.as_tensor(train_codes.lookup(s)).float() for s, _ in train["items"]])
    shape_index = torch.tensor([index[s] for s, _ in train["items"]])
    table = sdf_samples(world, ids, args.points * 4)
    samples = torch.stack([table[s] for s in ids])
    print(f"{len(x)} training views of {len(ids)} shapes, {samples.shape[1]} SDF samples each", flush=True)

    val = feature_file(args.world, "val", 1)
    val_ids = world.shape_ids("val")[: args.val]
    rows = {(s, v): i for i, (s, v) in enumerate(val["items"])}
    picked = [rows[(s, v)] for s in val_ids for v in (0, 6)]
    xv = encoder.head_input(val["features"][picked]).detach()
    yv = np.stack([np.asarray(val_codes.lookup(s)) for s in val_ids for _ in (0, 6)])
    mean_iou = views_iou(predictor, world, val_ids)

    def score(mu: torch.Tensor) -> dict:
        mu = mu.detach().numpy()
        return {"latent_l2": float(np.linalg.norm(mu - yv, axis=1).mean()), "iou": mean_iou(mu)}

    report = {"train_views": len(x), "val_views": len(xv), "points": args.points, "epochs": args.epochs}
    with torch.no_grad():
        report["shipped_heads"] = score(encoder.head(xv)[0])
    print("shipped heads", report["shipped_heads"], flush=True)
    report["weights"] = {}
    for weight in args.weights:
        t0 = time.time()
        head = train_head(x, y, shape_index, samples, decoder, weight, args.points, args.epochs)
        with torch.no_grad():
            row = score(head(xv)[0])
        row["seconds"] = round(time.time() - t0, 1)
        report["weights"][str(weight)] = row
        print(f"weight {weight}", row, flush=True)
        args.out.write_text(json.dumps(report, indent=1))
    report["seconds"] = round(time.time() - started, 1)
    args.out.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
