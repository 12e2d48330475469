"""The pose-and-shape refinement measured against the true cameras, on the held-out shapes of a model's world.

    PYTHONPATH=. python notebooks/pose_measure.py MODEL OUT.jsonl [--world W] [--shapes 30] [--views 1 3]
    PYTHONPATH=. python notebooks/pose_measure.py --summary OUT.jsonl

MODEL is an encoder run folder or `pretrained:<name>`, opened as reconstruct.py opens it. Per test shape and n
views (our renders, spread around the orbit): the fused code refined on the masks with the true cameras
(reconstruct.py's --refine masks) and with the cameras hidden (`refine_pose_and_shape`: K kept, the object's
pose in the first camera estimated; for n > 1 the views' motion from the first is given, as odometry would;
the hypotheses from the model's viewpoint head where it has one, unless --no-viewpoint).
--mode depth: both read the views' depth maps too (an RGB-D camera), the object's scale then estimated with its pose.
Kept: the rotation error of the estimate and of its runner-up, the pose's std, the Mahalanobis distance of the
rotation error, the seconds of each and the IoU of each against R2N2's voxels (+0.4 voxel). Resumable.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pretrained_measure import spread  # noqa: E402
from r2n2_ceiling import shape_frame  # noqa: E402

from ushape.data.layout import WorldIndex  # noqa: E402
from ushape.data.real.r2n2_voxels import read_r2n2_voxels  # noqa: E402
from ushape.decoder.query import code_sdf_fn  # noqa: E402
from ushape.encoder.datamodule import view_files  # noqa: E402
from ushape.metrics.voxel_iou import PROTOCOL_LEVEL, numpy_sdf, voxel_iou  # noqa: E402
from ushape.reconstruction.calibrated_fusion import default_fusion  # noqa: E402
from ushape.reconstruction.pose_calibration import pose_settings_for  # noqa: E402
from ushape.reconstruction.pretrained import open_model  # noqa: E402
from ushape.reconstruction.refine_calibration import read_refinement_calibration  # noqa: E402
from ushape.refinement import refine, refine_settings, world_views  # noqa: E402
from ushape.refinement.joint import PoseGroups, PoseSettings  # noqa: E402
from ushape.refinement.pose import Pose, log_so3, rotation_angle_deg  # noqa: E402
from ushape.refinement.pose_search import refine_from_poses, refine_pose_and_shape  # noqa: E402


def iou(decoder, code, voxels, frame) -> float:
    centre, scale, side = frame
    return voxel_iou(numpy_sdf(code_sdf_fn(decoder, code)), voxels, side, centre, scale, PROTOCOL_LEVEL)


def pose_row(decoder, fused, views, settings, pose_settings, azimuth_logp=None) -> dict:
    truth = Pose.from_world_to_cam(views[0].world_to_cam)
    groups = PoseGroups.from_cameras([v.world_to_cam for v in views])
    start = time.perf_counter()
    post = refine_pose_and_shape(decoder, fused.mu, fused.var, views, groups, settings, pose_settings, azimuth_logp)
    seconds = time.perf_counter() - start
    est, rec = post.poses[0], post.pose_record(0)
    omega = log_so3(est.R.T @ truth.R)  # the error in the state's own rotation coordinates
    cov = post.pose_cov[0].double()[:3, :3].numpy()
    runner = rec["runner_up"]
    return {
        "seconds": seconds,
        "code": post.mu,
        "rotation_error_deg": rotation_angle_deg(est.R, truth.R),
        "squared_over_var": float(omega @ omega / np.trace(cov)),
        "mahalanobis2": float(omega @ np.linalg.solve(cov, omega)),
        "rotation_std_deg": rec["rotation_std_deg"],
        "translation_error": float(np.linalg.norm(est.R.T @ (truth.t - est.t) / est.scale)),
        "translation_std": rec["translation_std"],
        # the object's origin in the first camera: along its axis (signed, + farther) and across it
        "depth_error": float(est.t[2] / est.scale - truth.t[2]),
        "lateral_error": float(np.linalg.norm(est.t[:2] / est.scale - truth.t[:2])),
        "scale": est.scale,  # the truth's is 1: the world's depth is in object units
        "ambiguous": rec["ambiguous"],
        "runner_up_error_deg": rotation_angle_deg(np.array(runner["R"]), truth.R) if runner else None,
        "runner_up_gap": runner["energy_gap"] if runner else None,
        "iterations": post.iterations,
    }


def oracle_row(decoder, fused, views, settings, pose_settings, voxels, frame) -> dict:
    truth = Pose.from_world_to_cam(views[0].world_to_cam)
    groups = PoseGroups.from_cameras([v.world_to_cam for v in views])
    start = time.perf_counter()
    post = refine_from_poses(decoder, fused.mu, fused.var, views, groups, [truth], settings, pose_settings)
    est = post.poses[0]
    return {
        "oracle_seconds": time.perf_counter() - start,
        "oracle_rotation_error_deg": rotation_angle_deg(est.R, truth.R),
        "oracle_translation_error": float(np.linalg.norm(est.R.T @ (truth.t - est.t) / est.scale)),
        "oracle_scale": est.scale,
        "oracle_iou": iou(decoder, post.mu, voxels, frame),
    }


def shape_rows(args, predictor, fusion, world, shape_id, done) -> list[dict]:
    decoder = predictor.decoder
    files = view_files(world.root, shape_id)
    images, _, _ = predictor.load_images(files)
    mu, var = predictor.encode(images)
    centre, scale, side, source = shape_frame(world, shape_id)
    voxels, _ = read_r2n2_voxels(source)
    frame = (centre, scale, side)
    fit = args.fit
    settings = refine_settings(args.mode, args.size, information_scale=fit["information_scale"] if fit else 1.0)
    rows = []
    for n in args.views:
        if (shape_id, n) in done:
            continue
        chosen = spread(n, len(files))
        fused = fusion(mu[chosen], var[chosen])
        views = world_views(world.views_path(shape_id), chosen, with_depth=args.mode == "depth")
        start = time.perf_counter()
        known = refine(decoder, fused.mu, fused.var, views, settings)
        known_seconds = time.perf_counter() - start
        logp = predictor.azimuth_log_probs(images[chosen]) if args.viewpoint else None
        est = pose_row(decoder, fused, views, settings, args.pose_settings, None if logp is None else list(logp))
        code = est.pop("code")
        if args.oracle:  # the joint refinement started at the true pose: what is left is not the search's
            est.update(oracle_row(decoder, fused, views, settings, args.pose_settings, voxels, frame))
        rows.append({
            "shape": shape_id, "views": n, "chosen": chosen,
            "fused_iou": iou(decoder, fused.mu, voxels, frame),
            "known_iou": iou(decoder, known.mu, voxels, frame), "known_seconds": known_seconds,
            "pose_iou": iou(decoder, code, voxels, frame), **est,
        })  # fmt: skip
    return rows


def summary(path: Path) -> dict:
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    out = {}
    for n in sorted({r["views"] for r in rows}):
        part = [r for r in rows if r["views"] == n]
        err = np.array([r["rotation_error_deg"] for r in part])
        flipped = err > 90
        runner = [r for r in part if r["rotation_error_deg"] > 30 and r["runner_up_error_deg"] is not None]
        good = ~flipped
        q = np.array([r["squared_over_var"] for r in part])[good]
        m2 = np.array([r["mahalanobis2"] for r in part])[good]
        out[n] = {
            "shapes": len(part),
            "rotation_error_median_deg": float(np.median(err)),
            "rotation_error_mean_deg_unflipped": float(err[good].mean()) if good.any() else None,
            "flipped": float(flipped.mean()),
            "wrong_over_30deg": float((err > 30).mean()),
            "runner_up_right_when_wrong": float(np.mean([r["runner_up_error_deg"] < 30 for r in runner]))
            if runner
            else None,
            "flagged_ambiguous": float(np.mean([r["ambiguous"] for r in part])),
            "squared_error_over_var_mean": float(q.mean()) if q.size else None,
            "coverage_90": float((m2 <= 6.2514).mean()) if m2.size else None,  # chi2(3) 90 %
            "iou_fused": float(np.mean([r["fused_iou"] for r in part])),
            "iou_known_camera": float(np.mean([r["known_iou"] for r in part])),
            "iou_pose_estimated": float(np.mean([r["pose_iou"] for r in part])),
            "seconds_known": float(np.mean([r["known_seconds"] for r in part])),
            "seconds_pose": float(np.mean([r["seconds"] for r in part])),
        }
        oracle = [r for r in part if "oracle_iou" in r]
        if oracle:
            out[n].update({
                "oracle_shapes": len(oracle),
                "iou_oracle_start": float(np.mean([r["oracle_iou"] for r in oracle])),
                "iou_known_camera_same_shapes": float(np.mean([r["known_iou"] for r in oracle])),
                "iou_pose_estimated_same_shapes": float(np.mean([r["pose_iou"] for r in oracle])),
                "oracle_rotation_error_median_deg": float(np.median([r["oracle_rotation_error_deg"] for r in oracle])),
                "oracle_translation_error_median": float(np.median([r["oracle_translation_error"] for r in oracle])),
            })  # fmt: skip
    return out


def pose_field(item: str) -> tuple[str, object]:
    """'name=value' -> (name, value) of a PoseSettings field, typed as its default is."""
    name, _, value = item.partition("=")
    default = getattr(PoseSettings(), name, None)
    if not value or name not in PoseSettings.__dataclass_fields__:
        raise SystemExit(
            f"--set {item}: expected FIELD=VALUE with FIELD one of {sorted(PoseSettings.__dataclass_fields__)}"
        )
    if isinstance(default, tuple):
        return name, tuple(float(v) for v in value.split(","))
    if default is None:
        return name, float(value)
    return name, type(default)(value)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", nargs="?")
    parser.add_argument("out", nargs="?", type=Path)
    parser.add_argument("--world", default=None)
    parser.add_argument("--split", default="test")
    parser.add_argument("--shapes", type=int, default=30)
    parser.add_argument("--views", type=int, nargs="+", default=[1, 3])
    parser.add_argument("--size", type=int, default=32, help="rays per image side (reconstruct.py's --refine-size)")
    parser.add_argument(
        "--mode",
        default="masks",
        choices=("masks", "depth"),
        help="what both refinements read: the masks, or the masks and the views' depth maps (an RGB-D camera)",
    )
    parser.add_argument("--summary", type=Path, default=None)
    parser.add_argument(
        "--no-viewpoint",
        dest="viewpoint",
        action="store_false",
        help="ignore the model's viewpoint head: hypotheses from the masks alone",
    )
    parser.add_argument(
        "--set",
        nargs="+",
        default=[],
        metavar="FIELD=VALUE",
        help="PoseSettings fields for this measurement, e.g. code_stages=4 (numbers; tuples as 8,4,2,1)",
    )
    parser.add_argument(
        "--oracle",
        action="store_true",
        help="also run the joint refinement from the true pose (refine_from_poses): the search's share of the gap",
    )
    parser.add_argument(
        "--grid-reuse",
        type=float,
        default=None,
        help="the pose search's grid reuse (PoseSettings.grid_reuse; 0: an SDF grid per code; default: the model's)",
    )
    args = parser.parse_args()
    if args.summary is not None:
        print(json.dumps(summary(args.summary), indent=1))
        return
    torch.manual_seed(0)
    predictor = open_model(args.model, temperature=True)
    if args.world is None and predictor.world is None:
        parser.error("this model names no world (a shipped model): pass --world, the r2n2 world it was measured on")
    world = WorldIndex.load(args.world or predictor.world)
    args.fit = read_refinement_calibration(predictor.checkpoint, args.mode)
    args.pose_settings = pose_settings_for(predictor.checkpoint, args.mode)  # its fitted pose information scale
    if args.grid_reuse is not None:
        args.pose_settings = replace(args.pose_settings, grid_reuse=args.grid_reuse)
    args.pose_settings = replace(args.pose_settings, **dict(pose_field(item) for item in args.set))
    fusion = default_fusion(predictor)
    done = set()
    if args.out.is_file():
        done = {(r["shape"], r["views"]) for r in map(json.loads, args.out.read_text().splitlines()) if r}
    for shape_id in world.shape_ids(args.split)[: args.shapes]:
        if all((shape_id, n) in done for n in args.views):
            continue
        rows = shape_rows(args, predictor, fusion, world, shape_id, done)
        with args.out.open("a") as f:
            f.writelines(json.dumps(r) + "\n" for r in rows)
        for r in rows:
            print(f"{shape_id} {r['views']}v rot {r['rotation_error_deg']:6.1f} (std {r['rotation_std_deg']:.1f}) "
                  f"runner {r['runner_up_error_deg']} IoU fused {r['fused_iou']:.3f} known {r['known_iou']:.3f} "
                  f"pose {r['pose_iou']:.3f} t {r['known_seconds']:.1f}/{r['seconds']:.1f} s", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
