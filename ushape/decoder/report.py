"""How good is a stage-1 decoder? Mesh its codes and score them against the ground truth.

    ushape report outputs/decoders/chairs-<hash> --shapes 8

For each split, the first `--shapes` shapes are meshed from their code (train: auto-decoded;
val/test: latent-optimised with the decoder frozen) and scored with DeepSDF's Chamfer
(30k points, sum of mean squared distances) and volumetric IoU at 64^3. Writes `report.json`
and one PNG per split (ground truth above, reconstruction below) into the decoder folder.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from ushape import atomic
from ushape.data.sdf_dataset import SDFSamplesDataset
from ushape.decoder.artifacts import DONE_FILE, codes_file, load_codes, load_decoder
from ushape.decoder.query import code_sdf_fn
from ushape.errors import InputError, MissingInputError
from ushape.mesh.extraction import EmptySurfaceError, extract_mesh
from ushape.mesh.preview import preview_image
from ushape.metrics.reconstruction import (
    chamfer_deepsdf,
    iou_from_occupancy,
    mesh_inside_fn,
    occupancy_grid,
    sdf_inside_fn,
)
from ushape.workspace import DECODER_REPORT_FILE as REPORT_FILE
from ushape.workspace import IDENTITY_FILE

log = logging.getLogger(__name__)


def score_split(decoder, world_root: Path, decoder_dir: Path, split: str, n_shapes: int, resolution: int) -> dict:
    """Chamfer/IoU per shape of one split, plus a picture strip; returns the split's summary."""
    table = load_codes(decoder_dir / codes_file(split))
    shapes = SDFSamplesDataset(world_root, split, samples_per_shape=2)  # the meshes stage 1 validated against
    rows, pictures = [], []
    for shape_id in table.shape_ids[:n_shapes]:
        gt = trimesh.load(shapes.mesh_path(shapes.shape_ids.index(shape_id)), force="mesh", process=False)
        sdf_fn = code_sdf_fn(decoder, table.lookup(shape_id))
        iou = iou_from_occupancy(occupancy_grid(mesh_inside_fn(gt), 64), occupancy_grid(sdf_inside_fn(sdf_fn), 64))
        try:
            mesh, _ = extract_mesh(sdf_fn, resolution)
            chamfer = chamfer_deepsdf(gt, mesh)
        except EmptySurfaceError:
            mesh, chamfer = None, float("nan")
        rows.append({"shape_id": shape_id, "chamfer": chamfer, "iou": iou})
        pictures.append(np.concatenate([preview_image(gt, 128), preview_image(mesh, 128)], axis=0))
    if pictures:
        with atomic.atomic_path(decoder_dir / f"report_{split}.png") as tmp:
            Image.fromarray(np.concatenate(pictures, axis=1)).save(tmp, format="PNG")
    chamfers = [r["chamfer"] for r in rows]
    return {
        "shapes": rows,
        "chamfer_mean": float(np.nanmean(chamfers)) if rows else None,
        "chamfer_median": float(np.nanmedian(chamfers)) if rows else None,
        "iou_mean": float(np.mean([r["iou"] for r in rows])) if rows else None,
        "empty": int(sum(np.isnan(chamfers))),
    }


def report(decoder_dir: str | Path, n_shapes: int = 8, resolution: int = 128, world: str | Path | None = None) -> dict:
    decoder_dir = Path(decoder_dir)
    identity = json.loads((decoder_dir / IDENTITY_FILE).read_text()) if (decoder_dir / IDENTITY_FILE).exists() else {}
    world_root = Path(world) if world is not None else _world_root(decoder_dir)
    decoder = load_decoder(decoder_dir)
    started = time.time()
    result = {"decoder_dir": str(decoder_dir), "world": str(world_root), "identity": identity, "resolution": resolution}
    for split in ("train", "val", "test"):
        result[split] = score_split(decoder, world_root, decoder_dir, split, n_shapes, resolution)
        log.info(
            "%s: chamfer %.5f (median %.5f), IoU %.3f",
            split,
            result[split]["chamfer_mean"],
            result[split]["chamfer_median"],
            result[split]["iou_mean"],
        )
    result["seconds"] = round(time.time() - started, 1)
    atomic.write_json(decoder_dir / REPORT_FILE, result)
    return result


def _world_root(decoder_dir: Path) -> Path:
    """The world a decoder was trained on, as fit_decoder recorded it in the DONE marker."""
    done = decoder_dir / DONE_FILE
    if not done.exists():
        raise MissingInputError(f"{decoder_dir} has no {DONE_FILE} marker: stage 1 has not finished there")
    root = json.loads(done.read_text()).get("world_root")
    if root is None:
        raise InputError(f"{done} does not record its world; pass --world /path/to/the/data/folder")
    return Path(root)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("decoder_dir")
    parser.add_argument("--shapes", type=int, default=8, help="shapes scored per split")
    parser.add_argument("--resolution", type=int, default=128, help="marching-cubes grid")
    parser.add_argument("--world", default=None, help="the data folder, if the decoder folder does not record it")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    result = report(args.decoder_dir, args.shapes, args.resolution, args.world)
    for split in ("train", "val", "test"):
        r = result[split]
        print(
            f"{split:5s}  Chamfer mean {r['chamfer_mean']:.5f}  median {r['chamfer_median']:.5f}  "
            f"IoU {r['iou_mean']:.3f}  empty {r['empty']}/{len(r['shapes'])}"
        )
    print(f"pictures: {Path(args.decoder_dir) / 'report_<split>.png'}")
