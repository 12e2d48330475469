"""Latent optimisation: seconds a code against the held-out IoU it reaches, per setting.

    PYTHONPATH=. python notebooks/latent_speed.py DECODER_DIR [--shapes 20] [--split val]
        [--settings 200x2000,200x1000,200x500,100x1000] [--lr 5e-3] [--out FILE.json]

Refits the first --shapes codes of a split (val by default; train refits the training shapes from
scratch, an oracle for the latent optimisation against the codes stage 1 trained) of the r2n2 world that
trained DECODER_DIR under several (iterations x samples a step) settings, the learning rate dropped at
3/4 of the iterations, all codes of a setting in one batched fit (`optimise_codes`), and
scores each code against R2N2's voxels (`ushape.metrics.voxel_iou`, level +0.4 voxel as
notebooks/r2n2_ceiling.py picks it). Seconds are wall time on this machine's threads.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from ushape.data.layout import WorldIndex
from ushape.data.real.r2n2_voxels import read_r2n2_voxels
from ushape.data.sdf_dataset import SDFSamplesDataset
from ushape.decoder.artifacts import DONE_FILE, load_decoder
from ushape.decoder.latent_optim import optimise_codes
from ushape.decoder.query import code_sdf_fn
from ushape.metrics.voxel_iou import PROTOCOL_LEVEL, numpy_sdf, voxel_iou

SETTINGS = "200x2000,200x1000,200x500,100x1000"  # iterations x samples a step


def parse_settings(text: str) -> list[tuple[int, int]]:
    """'200x1000,800x1000' -> [(200, 1000), (800, 1000)]"""
    try:
        return [(int(a), int(b)) for a, b in (item.split("x") for item in text.split(","))]
    except ValueError as error:
        raise SystemExit(f"--settings wants ITERATIONSxSAMPLES items joined by commas, got {text!r}") from error


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("decoder_dir", type=Path)
    parser.add_argument("--shapes", type=int, default=20)
    parser.add_argument("--split", default="val", choices=("train", "val", "test"))
    parser.add_argument("--settings", type=parse_settings, default=parse_settings(SETTINGS))
    parser.add_argument("--lr", type=float, default=5e-3, help="Adam's learning rate (the recipes': 5e-3)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    world = WorldIndex.load(json.loads((args.decoder_dir / DONE_FILE).read_text())["world_root"])
    decoder = load_decoder(args.decoder_dir).eval()
    shapes = SDFSamplesDataset(world.root, args.split, samples_per_shape=2)
    pairs = [shapes.samples(i) for i in range(min(args.shapes, len(shapes)))]
    samples = [(torch.cat([p, n])[:, :3], torch.cat([p, n])[:, 3]) for p, n in pairs]
    ids = shapes.shape_ids[: len(samples)]
    rows = []
    for iterations, per_step in args.settings:
        start = time.perf_counter()
        codes = optimise_codes(
            decoder,
            samples,
            iterations=iterations,
            samples_per_iter=per_step,
            lr=args.lr,
            lr_drop_at=int(iterations * 0.75),
        )
        seconds = (time.perf_counter() - start) / len(ids)
        ious = []
        for shape_id, code in zip(ids, codes):
            record = json.loads(world.shape_path(shape_id).read_text())
            voxels, _ = read_r2n2_voxels(record["source"])
            decoded = numpy_sdf(code_sdf_fn(decoder, code))
            side, centre, scale = record["voxel_side"], record["centre"], record["scale"]
            ious.append(voxel_iou(decoded, voxels, side, centre, scale, PROTOCOL_LEVEL))
        row = {
            "lr": args.lr,
            "iterations": iterations,
            "samples": per_step,
            "seconds_a_code": seconds,
            "iou": float(np.mean(ious)),
            "per_shape": dict(zip(ids, map(float, ious))),
        }
        rows.append(row)
        print(f"{iterations} x {per_step} samples at lr {args.lr:g}: {seconds:.2f} s a code, IoU {row['iou']:.3f}")
    if args.out:
        args.out.write_text(
            json.dumps(
                {"threads": torch.get_num_threads(), "split": args.split, "shapes": len(ids), "rows": rows}, indent=1
            )
        )


if __name__ == "__main__":
    main()
