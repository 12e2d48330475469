"""The decoder's ceiling on real shapes: held-out codes scored against 3D-R2N2's own 32^3 voxels.

    PYTHONPATH=. python notebooks/r2n2_ceiling.py DECODER_DIR [--split test] [--shapes 100] [--out FILE.json]
    PYTHONPATH=. python notebooks/r2n2_ceiling.py DECODER_DIR --split train --shapes 50 --level 0.4 [--world W]
    PYTHONPATH=. python notebooks/r2n2_ceiling.py DECODER_DIR --codes REFIT_DIR --split test --level 0.4

For each shape of the split of the r2n2 world that trained DECODER_DIR (its DONE names the world):
  - bound: the world's own voxel surface (the closed surface fitted to the voxels, stage 1's target),
    scored against the voxels at every level of `ushape.metrics.voxel_iou.LEVELS`;
  - ceiling: the shape's own code (latent-optimised on its SDF samples, codes_<split>.pt; from --codes DIR
    where given, e.g. notebooks/refit_codes.py's) under the frozen decoder, scored the same way.
The level is the one at which the bound is best on the val split (the first --shapes val shapes): the
voxelisation rule that reproduces R2N2's voxels from the surface they came from. Prints and writes
mean / median IoU of both at that level, and per shape.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import trimesh

from ushape.data.layout import WorldIndex
from ushape.data.real.r2n2_voxels import closed_mesh_sdf, read_r2n2_voxels
from ushape.decoder.artifacts import DONE_FILE, codes_file, load_codes, load_decoder
from ushape.decoder.query import code_sdf_fn
from ushape.metrics.voxel_iou import LEVELS, ious_at_levels, numpy_sdf


def shape_frame(world: WorldIndex, shape_id: str) -> tuple[np.ndarray, float, float, Path]:
    """(centre [3], scale, voxel side, voxel file) of a world shape: p_ours = (p_r2n2 - centre) * scale."""
    record = json.loads(world.shape_path(shape_id).read_text())
    return np.asarray(record["centre"]), float(record["scale"]), float(record["voxel_side"]), Path(record["source"])


def bound_and_ceiling(world: WorldIndex, decoder, codes, shape_id: str) -> tuple[np.ndarray, np.ndarray]:
    """IoU [L] of the world's voxel surface and of the own code's SDF with the voxels, at every level."""
    centre, scale, side, source = shape_frame(world, shape_id)
    voxels, _ = read_r2n2_voxels(source)
    surface = trimesh.load(world.mesh_path(shape_id), process=False)
    bound = ious_at_levels(lambda p: closed_mesh_sdf(surface, p), voxels, side, centre, scale)
    decoded = numpy_sdf(code_sdf_fn(decoder, codes.lookup(shape_id)))
    return bound, ious_at_levels(decoded, voxels, side, centre, scale)


def trained_world(parser: argparse.ArgumentParser, decoder_dir: Path, world: str | None) -> str:
    """The r2n2 world's root: `world` where given, else the one the stage-1 folder's DONE names."""
    done = decoder_dir / DONE_FILE
    if world is None and not done.is_file():
        parser.error(f"{decoder_dir} has no {DONE_FILE}: pass --world, the r2n2 world it was trained on")
    return world or json.loads(done.read_text())["world_root"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("decoder_dir", type=Path)
    parser.add_argument("--split", default="test")
    parser.add_argument("--shapes", type=int, default=100)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument(
        "--level",
        type=float,
        default=None,
        help="score at this level (voxels, one of LEVELS) and only --split: no val codes needed (e.g. --split train "
        "on a folder whose held-out codes are not latent-optimised yet)",
    )
    parser.add_argument("--world", default=None, help="the r2n2 world (default: the one DONE names)")
    parser.add_argument("--codes", type=Path, default=None, help="read codes_<split>.pt here (default: DECODER_DIR)")
    args = parser.parse_args()
    world = WorldIndex.load(trained_world(parser, args.decoder_dir, args.world))
    if args.level is not None and args.level not in LEVELS:
        parser.error(f"--level {args.level}: one of {LEVELS}")
    decoder = load_decoder(args.decoder_dir).eval()
    started = time.time()
    results = {}
    for split in ("val", args.split) if args.level is None else (args.split,):
        codes = load_codes((args.codes or args.decoder_dir) / codes_file(split))
        ids = world.shape_ids(split)[: args.shapes]
        rows = [bound_and_ceiling(world, decoder, codes, s) for s in ids]
        results[split] = {
            "ids": ids,
            "bound": np.stack([b for b, _ in rows]),
            "ceiling": np.stack([c for _, c in rows]),
        }
    if args.level is None:
        best = int(np.argmax(results["val"]["bound"].mean(axis=0)))
    else:
        best = LEVELS.index(args.level)
    level = float(LEVELS[best])
    report = {"decoder_dir": str(args.decoder_dir), "level_voxels": level, "levels": [float(v) for v in LEVELS]}
    for split, found in results.items():
        bound, ceiling = found["bound"][:, best], found["ceiling"][:, best]
        report[split] = {
            "shapes": len(found["ids"]),
            "bound_mean": float(bound.mean()),
            "bound_median": float(np.median(bound)),
            "ceiling_mean": float(ceiling.mean()),
            "ceiling_median": float(np.median(ceiling)),
            "ceiling_mean_by_level": found["ceiling"].mean(axis=0).round(4).tolist(),
            "bound_mean_by_level": found["bound"].mean(axis=0).round(4).tolist(),
            "per_shape": {s: [round(float(b), 4), round(float(c), 4)] for s, b, c in zip(found["ids"], bound, ceiling)},
        }
        print(
            f"{split}: {len(found['ids'])} shapes, level {level:+.1f} voxel: bound IoU {bound.mean():.3f} "
            f"(median {np.median(bound):.3f}), ceiling (own codes) {ceiling.mean():.3f} "
            f"(median {np.median(ceiling):.3f})"
        )
    report["seconds"] = round(time.time() - started, 1)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
