"""The figures of a real-shape model (docs/pretrained.md and its model card), on the held-out shapes of its r2n2 world.

    PYTHONPATH=. python notebooks/pretrained_measure.py MODEL OUT.jsonl [--world W] [--shapes 100] [--views 1 3 6 10 12]
    PYTHONPATH=. python notebooks/pretrained_measure.py --summary OUT.jsonl

MODEL is an encoder run folder or `pretrained:<name>`, opened as reconstruct.py opens it (its stored temperature
and fits applied). Per test shape and number of views n (our renders, spread around the orbit, true cameras):
the encoder's code from view 0, the views' fused code (the shared-error rule where fitted, as reconstruct.py),
and that code refined on the n views' masks (reconstruct.py's --refine masks: 32 rays a side, the fitted
information scale). Each is scored against R2N2's own 32^3 voxels (IoU at the level docs/pretrained.md chose,
+0.4 voxel) and against the world's surface (Chamfer, Pix3D protocol, 64^3 mesh); the shape's own code is the
ceiling. Latent |error| and std per dimension, and SDF |error| and linearised std at 256 ground-truth samples,
are kept for the calibration error. Rows are appended as they finish: a rerun skips what OUT holds.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent))
from r2n2_ceiling import shape_frame  # noqa: E402

from ushape.data.layout import WorldIndex  # noqa: E402
from ushape.data.real.r2n2_voxels import read_r2n2_voxels  # noqa: E402
from ushape.data.sdf_dataset import sdf_points  # noqa: E402
from ushape.decoder.artifacts import codes_file, load_codes  # noqa: E402
from ushape.decoder.query import code_sdf_fn  # noqa: E402
from ushape.encoder.datamodule import view_files  # noqa: E402
from ushape.mesh.extraction import EmptySurfaceError  # noqa: E402
from ushape.metrics.calibration import calibration_curve, calibration_error  # noqa: E402
from ushape.metrics.pix3d import pix3d_metrics, reference_from_mesh  # noqa: E402
from ushape.metrics.voxel_iou import PROTOCOL_LEVEL, numpy_sdf, voxel_iou  # noqa: E402
from ushape.propagation import SDF_CLAMP  # noqa: E402
from ushape.propagation.field import code_mesh  # noqa: E402
from ushape.propagation.linearised import latent_jacobian, latent_variance  # noqa: E402
from ushape.recalibration.refine_information import refined_sdf_temperature  # noqa: E402
from ushape.reconstruction.calibrated_fusion import default_fusion  # noqa: E402
from ushape.reconstruction.pretrained import open_model  # noqa: E402
from ushape.reconstruction.refine_calibration import read_refinement_calibration  # noqa: E402
from ushape.refinement import refine, refine_settings, world_views  # noqa: E402

REFINE_SIZE = 32  # reconstruct.py's --refine-size default


def spread(n: int, total: int) -> list[int]:
    """n views spread evenly around an orbit of `total` (view 0 first)."""
    return sorted({round(i * total / n) % total for i in range(n)})


def scores(decoder, code, voxels, frame, reference) -> dict:
    """IoU against the voxels and Chamfer against the surface of the decoder's shape for `code`."""
    centre, scale, side = frame
    values = numpy_sdf(code_sdf_fn(decoder, code))
    out = {"iou": voxel_iou(values, voxels, side, centre, scale, PROTOCOL_LEVEL)}
    try:
        mesh, _ = code_mesh(decoder, code, 64, "coarse_to_fine")
        inside = lambda p: values(np.asarray(p)) < 0  # noqa: E731
        out["cd"] = pix3d_metrics(mesh, inside, reference, emd=False)["cd"]
    except EmptySurfaceError:
        out["cd"] = None
    return out


def sdf_parts(decoder, code, cov, points, sdf_true, temperature: float = 1.0, floor: float = 0.0) -> dict:
    """|SDF error| and linearised std (x temperature, + floor^2) at the ground-truth samples, clamped as the
    evaluation clamps (no variance where the mean is beyond the clamp)."""
    sdf, g = latent_jacobian(decoder, code, points)
    var = latent_variance(g.double(), cov.double()) * temperature + floor**2
    near = sdf.abs() < SDF_CLAMP
    error = (sdf.clamp(-SDF_CLAMP, SDF_CLAMP) - sdf_true.clamp(-SDF_CLAMP, SDF_CLAMP)).abs()
    return {"abs_error": error[near].tolist(), "std": var.sqrt()[near].tolist()}


def shape_rows(args, predictor, fusion, world, codes, shape_id, done) -> list[dict]:
    decoder = predictor.decoder
    files = view_files(world.root, shape_id)
    images, _, _ = predictor.load_images(files)
    mu, var = predictor.encode(images)
    truth = codes.lookup(shape_id)
    centre, scale, side, source = shape_frame(world, shape_id)
    voxels, _ = read_r2n2_voxels(source)
    reference = reference_from_mesh(trimesh.load(world.mesh_path(shape_id), process=False))
    frame = (centre, scale, side)
    points, sdf_true = sdf_points(world, shape_id, 256)
    fit = args.fit
    options = refine_settings("masks", REFINE_SIZE, information_scale=fit["information_scale"] if fit else 1.0)
    sdf_t = predictor.sdf_temperature or 1.0
    base = {"shape": shape_id, "own": scores(decoder, truth, voxels, frame, reference)}
    base["encoder"] = scores(decoder, mu[0], voxels, frame, reference)
    rows = []
    for n in args.views:
        if (shape_id, n) in done or n > len(files):
            continue
        chosen = spread(n, len(files))
        fused = fusion(mu[chosen], var[chosen])
        start = time.perf_counter()
        post = refine(decoder, fused.mu, fused.var, world_views(world.views_path(shape_id), chosen), options)
        seconds = time.perf_counter() - start
        cov = post.cov if post.fallback is None else torch.diag(fused.var)
        refined_t = refined_sdf_temperature(fit, n) if fit and "sdf_temperature" in fit else 1.0
        refined_floor = fit.get("sdf_floor", 0.0) if fit else 0.0
        row = {**base, "views": n, "chosen": chosen}
        row["fused"] = scores(decoder, fused.mu, voxels, frame, reference)
        row["fused"]["latent"] = {"abs_error": (fused.mu - truth).abs().tolist(), "std": fused.var.sqrt().tolist()}
        row["fused"]["sdf"] = sdf_parts(decoder, fused.mu, torch.diag(fused.var), points, sdf_true, sdf_t)
        row["refined"] = scores(decoder, post.mu, voxels, frame, reference)
        row["refined"].update(seconds=round(seconds, 2), fallback=post.fallback, iterations=post.iterations)
        row["refined"]["latent"] = {
            "abs_error": (post.mu - truth).abs().tolist(),
            "std": cov.diagonal().sqrt().tolist(),
        }
        row["refined"]["sdf"] = sdf_parts(decoder, post.mu, cov, points, sdf_true, refined_t, refined_floor or 0.0)
        rows.append(row)
    return rows


def codes_dir(predictor, given: str | None) -> Path:
    """Where the model's stage-1 codes are: given, the run's decoder (run.json), or a shipped model's decoder/."""
    if given:
        return Path(given)
    record = Path(predictor.run_dir or "-") / "run.json"
    if record.is_file():
        return Path(json.loads(record.read_text())["decoder_dir"])
    return Path(predictor.checkpoint).parent / "decoder"


def summary(path: Path) -> dict:
    """Mean (median) IoU, mean Chamfer and calibration errors per views and estimate."""
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    out = {}
    for n in sorted({r["views"] for r in rows}):
        part = [r for r in rows if r["views"] == n]
        entry = {"shapes": len(part)}
        for kind in ("own", "encoder", "fused", "refined"):
            iou = np.array([r[kind]["iou"] for r in part])
            cd = np.array([r[kind]["cd"] for r in part if r[kind]["cd"] is not None])
            entry[kind] = {"iou": float(iou.mean()), "iou_median": float(np.median(iou)), "cd": float(cd.mean())}
            if kind in ("fused", "refined"):
                for space in ("latent", "sdf"):
                    err = torch.tensor([e for r in part for e in r[kind][space]["abs_error"]])
                    std = torch.tensor([s for r in part for s in r[kind][space]["std"]])
                    entry[kind][f"{space}_ce"] = calibration_error(*calibration_curve(err, std))
        seconds = [r["refined"]["seconds"] for r in part]
        entry["refined"]["seconds"] = float(np.mean(seconds))
        out[n] = entry
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", nargs="?")
    parser.add_argument("out", nargs="?", type=Path)
    parser.add_argument("--world", default=None, help="the r2n2 world (default: the model's own)")
    parser.add_argument("--codes", default=None, help="the folder of the decoder's codes (default: the model's)")
    parser.add_argument("--shapes", type=int, default=100)
    parser.add_argument("--views", type=int, nargs="+", default=[1, 3, 6, 10, 12])
    parser.add_argument("--summary", type=Path, default=None, help="print the summary of a finished OUT.jsonl")
    args = parser.parse_args()
    if args.summary is not None:
        print(json.dumps(summary(args.summary), indent=1))
        return
    predictor = open_model(args.model, temperature=True)
    world = WorldIndex.load(args.world or predictor.world)
    codes = load_codes(codes_dir(predictor, args.codes) / codes_file("test"))
    args.fit = read_refinement_calibration(predictor.checkpoint, "masks")
    fusion = default_fusion(predictor)
    done = set()
    if args.out.is_file():
        done = {(r["shape"], r["views"]) for r in map(json.loads, args.out.read_text().splitlines()) if r}
    for shape_id in world.shape_ids("test")[: args.shapes]:
        if all((shape_id, n) in done for n in args.views):
            continue
        started = time.perf_counter()
        rows = shape_rows(args, predictor, fusion, world, codes, shape_id, done)
        with args.out.open("a") as f:
            f.writelines(json.dumps(r) + "\n" for r in rows)
        line = ", ".join(f"{r['views']}: {r['fused']['iou']:.3f} -> {r['refined']['iou']:.3f}" for r in rows)
        print(f"{shape_id} own {rows[0]['own']['iou']:.3f} enc {rows[0]['encoder']['iou']:.3f} | {line} "
              f"({time.perf_counter() - started:.0f} s)", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
