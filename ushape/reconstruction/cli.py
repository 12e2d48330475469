"""Command line of reconstruct.py: argument parsing and what each mode runs (logic lives in the modules).

    python reconstruct.py IMAGE [IMAGE ... | FOLDER] [--run RUN | --checkpoint CKPT] [--out DIR]
        [--fusion average|bayesian|bayesian_k|shared|intersection] [--k 4] [--uncertainty mc|linearised]
        [--resolution 128] [--depth-method implicit|mc] [--precision auto|fp32|bf16] [--temperature] [--std-max S]
        [--refine masks|depth [--cameras CAMERAS.npz] [--masks MASK ...] [--refine-starts 8]] ...
    python reconstruct.py --fit-temperature [--run RUN | --checkpoint CKPT]
    python reconstruct.py --fit-refinement masks|depth [--run RUN | --checkpoint CKPT] [--refine-size 24]
    python reconstruct.py --fit-viewpoint [--run RUN | --checkpoint CKPT] [--viewpoint-shapes 1000]
    python reconstruct.py --fit-pose [--run RUN | --checkpoint CKPT] [--fit-shapes 20]
        [--fit-shapes 20]

Without --run/--checkpoint the newest encoder run under ./outputs/runs is used. The fusion rule is
built from the `fusion` config group (conf/fusion/<name>.yaml), with --k overriding its k. Without
--fusion: `shared` calibrated on the run's val split where --fit-temperature stored its fit, else bayesian.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path
from typing import Sequence

from hydra.errors import InstantiationException
from hydra.utils import instantiate
from omegaconf import OmegaConf

from ushape.decoder.precision import PRECISIONS
from ushape.fusion.rules import check_k
from ushape.mesh.extraction import EmptySurfaceError
from ushape.propagation.depth_implicit import DEPTH_METHODS
from ushape.propagation.mesh import METHODS
from ushape.reconstruction.calibrated_fusion import calibrate_fusion, default_fusion
from ushape.reconstruction.out_dir import check_out_dir
from ushape.reconstruction.pipeline import check_settings, reconstruct
from ushape.reconstruction.pose_calibration import fit_and_store_pose_calibration
from ushape.reconstruction.predictor import collect_inputs
from ushape.reconstruction.pretrained import PREFIX, available_models, open_model
from ushape.reconstruction.refine_calibration import FIT_SHAPES, fit_and_store_refinement_calibration
from ushape.reconstruction.settings import POSE_CHOICES, ReconstructionSettings
from ushape.reconstruction.temperature_store import fit_and_store_temperature
from ushape.reconstruction.viewpoint_store import fit_and_store_viewpoint
from ushape.refinement import MODES as REFINE_MODES
from ushape.refinement.inputs import input_views
from ushape.workspace import CONFIG_DIR

FUSION_CONFIGS = CONFIG_DIR / "fusion"
DEFAULT_OUT = Path("outputs") / "reconstructions"
DEFAULTS = ReconstructionSettings()  # every flag's default is the settings' own


def fusion_names() -> list[str]:
    return sorted(p.stem for p in FUSION_CONFIGS.glob("*.yaml"))


def build_fusion(name: str, k: int | None = None):
    """The fusion callable of conf/fusion/<name>.yaml (k overrides the config's k where it has one)."""
    path = FUSION_CONFIGS / f"{name}.yaml"
    if not path.is_file():
        raise ValueError(f"unknown fusion {name!r}; choose one of {fusion_names()}")
    config = OmegaConf.load(path)
    if k is not None and "k" in config:
        config.k = check_k(k)
    try:
        return instantiate(config)
    except InstantiationException as err:  # Hydra wraps the rule's own ValueError in a long traceback
        raise ValueError(f"fusion {name}: {err.__cause__ or err}") from err


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description="3D shape with uncertainty from one or more images.")
    parser.add_argument("inputs", nargs="*", help="image files and/or folders of images (views of one object)")
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--run", help="run folder of `python train.py` (default: the newest encoder run)")
    source.add_argument("--checkpoint", help="an encoder .ckpt instead of a run folder")
    source.add_argument(
        "--model",
        default=None,
        help=f"a model shipped with ushape, by name ({', '.join(available_models()) or 'none in this installation'}), "
        "or an exported model folder's path; calibrated: its temperature and fusion fit apply",
    )
    parser.add_argument("--root", default=".", help="where outputs/runs is searched for the newest run")
    parser.add_argument(
        "--fit-temperature",
        action="store_true",
        help="fit T (var' = T var) on the run's val split and store temperature.json, then exit",
    )
    parser.add_argument(
        "--fit-refinement",
        default=None,
        choices=REFINE_MODES,
        help="fit the refined posterior's calibration for this mode on val shapes (after --fit-temperature: the "
        "prior is the calibrated fusion) and store refinement_calibration.json; --refine then applies it",
    )
    parser.add_argument(
        "--fit-shapes",
        type=int,
        default=FIT_SHAPES,
        help="with --fit-refinement: how many val shapes to refine and fit on (the first ones; all where fewer)",
    )
    parser.add_argument(
        "--fit-viewpoint",
        action="store_true",
        help="fit the camera-azimuth head on the run's train renders (scored on val) and store viewpoint.pt, which "
        "the pose estimation of --refine masks then starts from (docs/pose.md)",
    )
    parser.add_argument(
        "--fit-pose",
        nargs="?",
        const="masks",
        default=None,
        choices=REFINE_MODES,
        help="fit the pose posterior's information scale for --refine masks (the default) or depth on --fit-shapes "
        "val shapes (1 and 3 views, cameras hidden; after --fit-viewpoint and --fit-refinement of that mode) and "
        "store it in pose_calibration.json (docs/pose.md)",
    )
    parser.add_argument(
        "--viewpoint-shapes",
        type=int,
        default=None,
        help="with --fit-viewpoint: how many train shapes' renders to fit on (default: all)",
    )
    parser.add_argument("--temperature", action="store_true", help="apply the stored temperature")
    parser.add_argument(
        "--fusion",
        default=None,
        help="average | bayesian | bayesian_k | shared | intersection (conf/fusion); default: shared where "
        "--fit-temperature fitted it, else bayesian",
    )
    parser.add_argument("--k", type=int, default=None, help="views kept by bayesian_k / shared (default: conf)")
    parser.add_argument("--uncertainty", default=DEFAULTS.uncertainty, choices=METHODS, help="vertex std propagation")
    parser.add_argument("--samples", type=int, default=DEFAULTS.n_samples, help="codes for --uncertainty mc")
    parser.add_argument(
        "--resolution", type=int, default=DEFAULTS.resolution, help="marching-cubes grid points per axis"
    )
    parser.add_argument("--depth-size", type=int, default=DEFAULTS.depth_size, help="depth-map pixels per side")
    parser.add_argument(
        "--depth-method",
        default=DEFAULTS.depth_method,
        choices=DEPTH_METHODS,
        help="depth std: implicit (trace the mean code once, first order) or mc (trace M sampled codes)",
    )
    parser.add_argument(
        "--depth-codes", type=int, default=DEFAULTS.depth_codes, help="codes M traced per depth map (--depth-method mc)"
    )
    parser.add_argument(
        "--std-max",
        type=float,
        default=None,
        help="top of the colour scale (default: the 99th percentile of the mesh's stds)",
    )
    parser.add_argument(
        "--refine",
        default=None,
        choices=REFINE_MODES,
        help="refine the fused code on what the views show (masks, or masks + depth) through their cameras, or "
        "with the object's pose estimated (--pose)",
    )
    parser.add_argument(
        "--cameras",
        default=None,
        help="npz with K [V,3,3], world_to_cam [V,4,4] (optional masks, depth) per input image, in order "
        "(default: a render's own views.npz)",
    )
    parser.add_argument(
        "--masks",
        nargs="+",
        default=None,
        help="one mask image per input, white = object (default: each image's alpha): cuts the object out for the "
        "encoder, and is what --refine fits",
    )
    parser.add_argument(
        "--refine-size", type=int, default=DEFAULTS.refine_size, help="rays per image side the refinement compares"
    )
    parser.add_argument(
        "--refine-starts",
        type=int,
        default=DEFAULTS.refine_starts,
        help="prior draws scored beside the fused mean, the refinement starting from the lowest energy (0: the mean; "
        "8 found better basins on chairs from 6 depth views, docs/refinement.md)",
    )
    parser.add_argument(
        "--pose",
        default=DEFAULTS.pose,
        choices=POSE_CHOICES,
        help="estimate the object's pose with its shape (auto: with --refine masks where no image has a camera; "
        "estimate: always, a known camera's K kept, a camera file's world_to_cam optional; given: never); with "
        "--refine depth the depth maps give the object's distance and size in their units, docs/pose.md",
    )
    parser.add_argument(
        "--fov",
        type=float,
        default=DEFAULTS.fov,
        help="field of view in degrees across the larger side of an image with no camera (default: R2N2's renders')",
    )
    parser.add_argument(
        "--relative-poses",
        default=None,
        help="npz with world_to_cam [V,4,4] of the images in any one frame (odometry, a turntable): the images "
        "share one estimated object pose and only their motion between each other is used",
    )
    parser.add_argument(
        "--elevation",
        type=float,
        default=DEFAULTS.elevation,
        help="with the pose estimated: the cameras' elevation above the object's ground plane in degrees, where the "
        "hypotheses start (default: R2N2's renders', 27.5)",
    )
    parser.add_argument(
        "--tilt-std",
        type=float,
        default=DEFAULTS.tilt_std,
        help="with the pose estimated: the prior's std in degrees of the object's tilt from --elevation (rotation "
        "about its horizontal axes; default: the rotation's own). 3 for R2N2-style renders (elevation 25-30, "
        "no camera roll), docs/pose.md",
    )
    parser.add_argument("--cmap", default=DEFAULTS.cmap, help="matplotlib colormap for the std colours")
    parser.add_argument(
        "--precision",
        default=DEFAULTS.precision,
        choices=PRECISIONS,
        help="decoder precision: auto (bf16 on AMX CPUs and CUDA >= 8.0, else fp32), fp32 or bf16",
    )
    parser.add_argument("--seed", type=int, default=DEFAULTS.seed)
    parser.add_argument("--out", default=None, help=f"output folder (default {DEFAULT_OUT}/<time>)")
    return parser


def predictor_of(args: argparse.Namespace, temperature: bool):
    """The model the flags name: a shipped one (--model, always calibrated), a run or checkpoint, or the newest run."""
    source = f"{PREFIX}{args.model}" if args.model else args.checkpoint or args.run
    return open_model(source, temperature=temperature, root=args.root)


def settings_from(args: argparse.Namespace) -> ReconstructionSettings:
    """The reconstruction's settings from its flags (their defaults are ReconstructionSettings')."""
    return ReconstructionSettings(
        resolution=args.resolution,
        uncertainty=args.uncertainty,
        n_samples=args.samples,
        depth_size=args.depth_size,
        depth_method=args.depth_method,
        depth_codes=args.depth_codes,
        std_max=args.std_max,
        cmap=args.cmap,
        seed=args.seed,
        refine=args.refine,
        refine_size=args.refine_size,
        refine_starts=args.refine_starts,
        pose=args.pose,
        fov=args.fov,
        relative_poses=args.relative_poses,
        elevation=args.elevation,
        tilt_std=args.tilt_std,
        precision=args.precision,
    )


def refinement_outcome(record: dict) -> str:
    """One line: whether the code was refined, on how many views and what each view that gave less was missing."""
    head = f"refinement ({record['mode']}, {record['iterations']} iterations)"
    if record["fallback"]:
        return f"{head}: not refined, the fused code is kept: {record['fallback']}"
    views = record.get("views") or []
    used = [v for v in views if v["used"]]
    notes = "; ".join(f"view {i}: {v['fallback']}" for i, v in enumerate(views) if v["fallback"])
    with_depth = sum(v["used"] == "masks+depth" for v in views)
    depth = f", depth from {with_depth}" if record["mode"] == "depth" else ""
    line = f"{head}: refined on {len(used)} of {len(views)} views{depth}" + (f" ({notes})" if notes else "")
    return line + "".join(f"\n  {pose_outcome(g, i)}" for i, g in enumerate(record.get("pose", {}).get("groups", [])))


def pose_outcome(group: dict, index: int) -> str:
    """One line per estimated pose: its std, its scale where a baseline or a depth map makes it observable, and
    the runner-up where the views leave the pose ambiguous."""
    line = (
        f"pose {index} estimated (no camera given): rotation std {group['rotation_std_deg']:.1f} deg, translation std "
        f"{max(group['translation_std']):.3f} object units"
    )
    if group.get("scale_std") is not None:
        line += f", scale {group['scale']:.3f} (log std {group['scale_std']:.3f})"
    runner = group.get("runner_up")
    if runner is not None:
        verdict = "AMBIGUOUS: " if group["ambiguous"] else ""
        line += (
            f"; {verdict}runner-up {runner['rotation_from_best_deg']:.0f} deg away, energy gap "
            f"{runner['energy_gap']:.1f}"
        )
    return line


def main(argv: Sequence[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(message)s")
    args = build_parser().parse_args(argv)
    try:
        if args.fit_temperature:
            predictor = predictor_of(args, temperature=False)
            record = fit_and_store_temperature(predictor)
            print(json.dumps(record, indent=2))
            return 0
        if args.fit_viewpoint:
            record = fit_and_store_viewpoint(predictor_of(args, temperature=False), args.viewpoint_shapes)
            print(json.dumps(record, indent=2))
            return 0
        if args.fit_pose:
            predictor = predictor_of(args, temperature=True)
            record = fit_and_store_pose_calibration(predictor, args.fit_shapes, mode=args.fit_pose)
            print(json.dumps(record, indent=2))
            return 0
        if args.fit_refinement:
            predictor = predictor_of(args, temperature=True)
            record = fit_and_store_refinement_calibration(
                predictor, args.fit_refinement, size=args.refine_size, n_shapes=args.fit_shapes
            )
            print(json.dumps(record, indent=2))
            return 0
        settings = settings_from(args)
        check_settings(settings)
        out = check_out_dir(Path(args.out) if args.out else DEFAULT_OUT / time.strftime("%Y-%m-%d_%H-%M-%S"))
        if args.cameras and not args.refine:
            raise ValueError("--cameras is read by the refinement: add --refine masks|depth")
        files = collect_inputs(args.inputs)
        given = args.cameras or args.masks
        unknown = args.pose == "estimate"  # a camera file may then hold K (and depth) with no world_to_cam
        observations = None
        if args.refine and given:
            observations = input_views(files, args.cameras, args.masks, pose_unknown=unknown)
        fusion = build_fusion(args.fusion, args.k) if args.fusion else None
        predictor = predictor_of(args, temperature=args.temperature)
        fusion = default_fusion(predictor, args.k) if fusion is None else calibrate_fusion(fusion, predictor)
        summary = reconstruct(predictor, files, fusion, out, settings, observations, args.masks)
    except EmptySurfaceError as err:
        print(
            f"error: the fused code's SDF has no surface in [-1, 1]^3 ({err}); try other views or --fusion",
            file=sys.stderr,
        )
        return 2
    except (FileNotFoundError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    kept = summary["fused"]["kept"]
    calibration = summary["fusion_calibration"]
    print(
        f"{len(summary['views'])} view(s), fused {kept} with {summary['fusion']}"
        f" ({calibration or 'views treated as independent'}); "
        f"mesh {summary['mesh']['vertices']} vertices -> {out}"
    )
    if summary["refinement"] is not None:
        print(f"  {refinement_outcome(summary['refinement'])}")
    for name, path in summary["files"].items():
        print(f"  {name}: {path}")
    return 0
