"""Would fine-tuning the backbone's last stages lift the one-view code? A cheap probe on cached maps.

    PYTHONPATH=. python notebooks/finetune_probe.py MODEL WORLD OUT.json [--train 300] [--val 100] [--epochs 20]

MODEL as notebooks/pretrained_measure.py takes it. Its frozen EfficientNet-Lite0 reads the training shapes' 12
renders and the val shapes' views 0 and 6 once, up to the end of stage 5 (112 channels at 1/16 of the image);
those maps are cached. Two regressors to the model's training codes (L2 loss, the same MLP head, AdamW) are then
trained on the training views and scored on the val views:
- `frozen`: the head on the stage means the shipped heads read (stages 6-7 and the 1x1 head conv frozen);
- `finetuned`: the same, with stages 6-7 and the head conv trained too (lr 10x lower than the head's; batch
  norm keeps its ImageNet statistics), the first five stages' means frozen.
Both start from the same head weights and see the same batches. Scored: latent L2 against the shapes' codes
(train and val) and IoU against R2N2's voxels at +0.4 voxel on val (as pretrained_measure.py).
"""

from __future__ import annotations

import copy
import json
import sys
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parent))
from feature_probe import probe_parser, views_iou  # noqa: E402
from pretrained_measure import codes_dir  # noqa: E402

from ushape.data.layout import WorldIndex  # noqa: E402
from ushape.decoder.artifacts import codes_file, load_codes  # noqa: E402
from ushape.encoder.datamodule import view_files  # noqa: E402
from ushape.reconstruction.pretrained import open_model  # noqa: E402

SPLIT_BLOCK = 10  # the last block of stage 5; blocks 11-15 are stages 6 and 7


class Upper(nn.Module):
    """Stages 6-7 and the head conv of a Lite0 on cached stage-5 maps [B, 112, h, w] -> stage means [B, 1792]."""

    def __init__(self, backbone) -> None:
        super().__init__()
        self.blocks = nn.ModuleList(copy.deepcopy(backbone._blocks[SPLIT_BLOCK + 1 :]))
        self.ends = {i - SPLIT_BLOCK - 1 for i in backbone._stage_ends if i > SPLIT_BLOCK}
        self.conv_head, self.bn = copy.deepcopy(backbone._conv_head), copy.deepcopy(backbone._bn1)
        self.requires_grad_(True)  # the loaded model's backbone is frozen: its copies would be too

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        pooled = []
        for i, block in enumerate(self.blocks):
            x = block(x)
            if i in self.ends:
                pooled.append(x.mean(dim=(-2, -1)))
        return torch.cat([*pooled, F.relu6(self.bn(self.conv_head(x))).mean(dim=(-2, -1))], dim=1)


class Standardise(nn.Module):
    """(x - mean) / std with fixed statistics [F]."""

    def __init__(self, mean: torch.Tensor, std: torch.Tensor) -> None:
        super().__init__()
        self.register_buffer("mean", mean)
        self.register_buffer("std", std)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.mean) / self.std


@torch.no_grad()
def lower(encoder, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """images [B, 3, S, S] in [0, 1] -> (stage 1-5 means [B, 272], stage-5 maps [B, 112, S/16, S/16])."""
    maps = encoder.backbone.stage_maps((images - encoder.pixel_mean) / encoder.pixel_std, SPLIT_BLOCK + 1)
    return torch.cat([m.mean(dim=(-2, -1)) for m in maps], dim=1), maps[-1]  # SPLIT_BLOCK ends stage 5


def train(upper, head, data, codes, epochs: int, finetune: bool, seed: int = 0) -> None:
    """L2 regression of codes [N, D] from (lower means [N, 272], maps [N, 112, h, w]); in place."""
    groups = [{"params": head.parameters(), "lr": 1e-3}]
    if finetune:
        groups.append({"params": upper.parameters(), "lr": 1e-4})
    opt = torch.optim.AdamW(groups, weight_decay=0.05)
    generator = torch.Generator().manual_seed(seed)
    means, maps = data
    upper.eval()  # batch norm keeps ImageNet's statistics: batches of 64 4x4 maps would not estimate them
    head.train()
    if not finetune:  # the frozen stages' features, once for every epoch
        with torch.no_grad():
            fixed = torch.cat([upper(x) for x in maps.split(256)])
    for _ in range(epochs):
        for batch in torch.randperm(len(codes), generator=generator).split(64):
            feats = upper(maps[batch]) if finetune else fixed[batch]
            loss = (head(torch.cat([means[batch], feats], 1)) - codes[batch]).square().sum(1).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()


@torch.no_grad()
def predict(upper, head, data) -> torch.Tensor:
    upper.eval()
    head.eval()
    means, maps = data
    return torch.cat([head(torch.cat([m, upper(x)], 1)) for m, x in zip(means.split(256), maps.split(256))])


def main() -> None:
    parser = probe_parser(__doc__)
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument("--variants", nargs="+", default=["frozen", "finetuned"], choices=["frozen", "finetuned"])
    args = parser.parse_args()
    started = time.time()
    torch.manual_seed(0)
    predictor = open_model(args.model)
    encoder = predictor.model.encoder.eval()
    world = WorldIndex.load(args.world)
    folder = codes_dir(predictor, None)
    tables = {"train": load_codes(folder / codes_file("train")), "val": load_codes(folder / codes_file("val"))}

    def read(split: str, ids: list[str], views: list[int] | None):
        means, maps, codes = [], [], []
        for shape_id in ids:
            files = view_files(world.root, shape_id)
            images, _, _ = predictor.load_images([files[v] for v in views] if views else files)
            m, x = lower(encoder, images)
            means.append(m)
            maps.append(x)
            codes += [tables[split].lookup(shape_id).float()] * len(images)
        return (torch.cat(means), torch.cat(maps)), torch.stack(codes)

    val_ids = world.shape_ids("val")[: args.val]
    train_data, train_codes = read("train", world.shape_ids("train")[: args.train], None)
    val_data, val_codes = read("val", val_ids, [0, 6])
    mean_iou = views_iou(predictor, world, val_ids)

    with torch.no_grad():  # the head reads features standardised by the frozen ones' training statistics
        frozen = torch.cat([train_data[0], Upper(encoder.backbone).eval()(train_data[1])], 1)
    standardise = Standardise(frozen.mean(0), frozen.std(0) + 1e-6)
    start_head = nn.Sequential(
        standardise, nn.Linear(frozen.shape[1], 512), nn.ReLU(), nn.Dropout(0.3), nn.Linear(512, train_codes.shape[1])
    )
    report = {"train_views": len(train_codes), "val_views": len(val_codes), "epochs": args.epochs}
    for name in args.variants:
        finetune = name == "finetuned"
        upper, head = Upper(encoder.backbone), copy.deepcopy(start_head)
        upper.requires_grad_(finetune)
        began = time.time()
        train(upper, head, train_data, train_codes, args.epochs, finetune)
        train_pred, val_pred = predict(upper, head, train_data), predict(upper, head, val_data)
        report[name] = {
            "train_latent_l2": float((train_pred - train_codes).norm(dim=1).mean()),
            "val_latent_l2": float((val_pred - val_codes).norm(dim=1).mean()),
            "val_iou": mean_iou(val_pred),
            "seconds": round(time.time() - began, 1),
        }
        print(name, report[name], flush=True)
    report["seconds"] = round(time.time() - started, 1)
    args.out.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
