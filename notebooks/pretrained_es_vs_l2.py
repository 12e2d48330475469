"""Encoder only, single views: a real-shape model against its FroDO* (L2) twin trained on the same cached features.

    PYTHONPATH=. python notebooks/pretrained_es_vs_l2.py ES_MODEL L2_MODEL WORLD [--shapes 100] [--views 0 6]
        [--split test]

ES_MODEL / L2_MODEL: `pretrained:<name>` or run folders. Each test shape's views (`--split train`: each
training shape's, the heads' own fit) are encoded by both, and each code scored against R2N2's 32^3 voxels at
+0.4 voxel (as notebooks/pretrained_measure.py); prints a row a shape, then the means and how often ES scores
higher.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from r2n2_ceiling import shape_frame  # noqa: E402

from ushape.data.layout import WorldIndex  # noqa: E402
from ushape.data.real.r2n2_voxels import read_r2n2_voxels  # noqa: E402
from ushape.decoder.query import code_sdf_fn  # noqa: E402
from ushape.encoder.datamodule import view_files  # noqa: E402
from ushape.metrics.voxel_iou import PROTOCOL_LEVEL, numpy_sdf, voxel_iou  # noqa: E402
from ushape.reconstruction.pretrained import open_model  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("es")
    parser.add_argument("l2")
    parser.add_argument("world")
    parser.add_argument("--shapes", type=int, default=100)
    parser.add_argument("--views", type=int, nargs="+", default=[0, 6])
    parser.add_argument("--split", default="test", help="train: the views the heads were trained on (their fit)")
    args = parser.parse_args()
    world = WorldIndex.load(args.world)
    models = {"ES": open_model(args.es, temperature=args.es.startswith("pretrained:")), "L2": open_model(args.l2)}
    scores = {name: [] for name in models}
    for shape_id in world.shape_ids(args.split)[: args.shapes]:
        centre, scale, side, source = shape_frame(world, shape_id)
        voxels, _ = read_r2n2_voxels(source)
        files = view_files(world.root, shape_id)
        row = {"shape": shape_id}
        for name, predictor in models.items():
            images, _, _ = predictor.load_images([files[v] for v in args.views])
            mu, _ = predictor.encode(images)
            row[name] = []
            for code in mu:
                values = numpy_sdf(code_sdf_fn(predictor.decoder, code))
                row[name].append(voxel_iou(values, voxels, side, centre, scale, PROTOCOL_LEVEL))
            scores[name] += row[name]
        print(json.dumps(row), flush=True)
    es, l2 = np.array(scores["ES"]), np.array(scores["L2"])
    summary = {"views": len(es), "ES": float(es.mean()), "L2": float(l2.mean()), "ES_better": float((es > l2).mean())}
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
