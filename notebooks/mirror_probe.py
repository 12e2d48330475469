"""Does the encoder read more from one view with its mirror image beside it? A test-time augmentation probe.

    PYTHONPATH=. python notebooks/mirror_probe.py MODEL WORLD [--shapes 100] [--views 0 6]

MODEL as notebooks/pretrained_measure.py takes it. Chairs and tables are nearly symmetric left to right, and the
encoder predicts the code in the object's own frame, so a view mirrored left to right shows (nearly) the same
object from the mirrored azimuth: a second opinion on the same code at the cost of one more backbone pass.
Per test shape and view: IoU against R2N2's voxels (+0.4 voxel) of the code from the view (`plain`), from its
mirror (`mirror`), and of their mean (`mean`) and precision-weighted mean (`weighted`); the paired difference
mean - plain with its standard error.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pose_measure import iou  # noqa: E402
from r2n2_ceiling import shape_frame  # noqa: E402

from ushape.data.layout import WorldIndex  # noqa: E402
from ushape.data.real.r2n2_voxels import read_r2n2_voxels  # noqa: E402
from ushape.encoder.datamodule import view_files  # noqa: E402
from ushape.reconstruction.pretrained import open_model  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model")
    parser.add_argument("world")
    parser.add_argument("--shapes", type=int, default=100)
    parser.add_argument("--views", type=int, nargs="+", default=[0, 6])
    args = parser.parse_args()
    predictor = open_model(args.model, temperature=True)
    world = WorldIndex.load(args.world)
    scores = {"plain": [], "mirror": [], "mean": [], "weighted": []}
    for shape_id in world.shape_ids("test")[: args.shapes]:
        centre, scale, side, source = shape_frame(world, shape_id)
        voxels = read_r2n2_voxels(source)[0]
        files = view_files(world.root, shape_id)
        images, _, _ = predictor.load_images([files[v] for v in args.views])
        mu, var = predictor.encode(images)
        mirror_mu, mirror_var = predictor.encode(torch.flip(images, dims=[-1]))
        weighted = (mu / var + mirror_mu / mirror_var) / (1 / var + 1 / mirror_var)
        codes = {"plain": mu, "mirror": mirror_mu, "mean": 0.5 * (mu + mirror_mu), "weighted": weighted}
        for name, rows in codes.items():
            scores[name] += [iou(predictor.decoder, code, voxels, (centre, scale, side)) for code in rows]
    print({name: round(float(np.mean(values)), 4) for name, values in scores.items()}, f"{len(scores['plain'])} views")
    gain = np.array(scores["mean"]) - np.array(scores["plain"])
    print(f"mean - plain: {gain.mean():+.4f} +- {gain.std(ddof=1) / np.sqrt(len(gain)):.4f}")


if __name__ == "__main__":
    main()
