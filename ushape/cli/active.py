"""`ushape active` / `python active.py`: one object reconstructed view by view, the next view chosen by a strategy.

    python active.py                                   newest run, its world's first test shape, guided, 6 views
    python active.py --shape chairs_123 --strategy farthest --views 8 --min-scale 0.1
    python active.py --run outputs/runs/<date>/<run> --candidates recorded   # choose among the recorded views
    python active.py --strategy information --observe masks   # expected information gain, refined on the masks

Writes into --out: sequence.png (each view taken, the mesh coloured by its SDF std after it, the scores
that chose the next view), views/step_K.png (what the encoder saw), step_K.ply/.glb (the mesh after K
views with per-vertex std) and summary.json; prints each step, with IoU and Chamfer against the world's
ground truth. The start view is the one `eval.py protocols=[active]` starts that shape from.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np
from PIL import Image

from ushape import atomic
from ushape.data.world import open_world
from ushape.decoder.latent_gaussian import latent_trace
from ushape.evaluation.code_metrics import Reconstructor
from ushape.evaluation.plots import save_figure
from ushape.planning import (
    SequenceContext,
    ViewEncoder,
    active_reconstruction,
    build_observer,
    build_strategy,
    candidate_views,
)
from ushape.planning.candidates import SOURCES
from ushape.planning.figures import sequence_figure, step_surfaces
from ushape.planning.plugins import strategy_names
from ushape.planning.sequence import loop_fusion, start_view
from ushape.reconstruction.export import DEFAULT_CMAP, colour_range, coloured_mesh, write_colour_bar, write_mesh_files
from ushape.reconstruction.pretrained import PREFIX, open_model
from ushape.reconstruction.report_page import Scene, write_report
from ushape.workspace import SUMMARY_FILE

DEFAULT_OUT = Path("outputs") / "active"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description="Active reconstruction: let a strategy choose each next view.")
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--run", help="run folder of `python train.py` (default: the newest encoder run)")
    source.add_argument("--checkpoint", help="an encoder .ckpt instead of a run folder")
    source.add_argument(
        "--model",
        help="a model shipped with ushape, by name, or an exported model folder's path (needs --world: its data world)",
    )
    parser.add_argument("--root", default=".", help="where outputs/runs is searched for the newest run")
    parser.add_argument("--world", default=None, help="the world folder (default: the run's own)")
    parser.add_argument("--split", default="test", help="the split the shape is taken from")
    parser.add_argument("--shape", default=None, help="shape id (default: the split's first)")
    parser.add_argument(
        "--strategy",
        default="uncertainty",
        help=f"how the next view is chosen: {', '.join(strategy_names())}, or a file of --strategy-dir",
    )
    parser.add_argument("--strategy-dir", action="append", default=[], help="a folder of strategy YAML files")
    parser.add_argument(
        "--observe",
        default="none",
        help="after each view: none (the fused Gaussian), or refine it on every view taken (masks, depth), "
        "or a file of --observer-dir",
    )
    parser.add_argument("--observer-dir", action="append", default=[], help="a folder of observer YAML files")
    parser.add_argument("--refine-size", type=int, default=24, help="rays per image side (refinement, information)")
    parser.add_argument("--refine-iterations", type=int, default=15, help="Levenberg-Marquardt steps at most")
    parser.add_argument("--views", type=int, default=6, help="views to acquire, the start view included")
    parser.add_argument("--start", type=int, default=None, help="start candidate (default: as eval.py's protocol)")
    parser.add_argument("--min-scale", type=float, default=1.0, help="crop each view to a random area in [s, 1]")
    parser.add_argument("--candidates", default="auto", choices=SOURCES, help="orbit renders, or the recorded views")
    parser.add_argument("--azimuths", type=int, default=12, help="orbit candidates: azimuths over [0, 360)")
    parser.add_argument("--elevations", type=int, default=2, help="orbit candidates: elevations over 25-30 deg")
    parser.add_argument("--resolution", type=int, default=64, help="marching-cubes grid of the meshes")
    parser.add_argument("--temperature", action="store_true", help="apply the stored variance temperature")
    parser.add_argument("--seed", type=int, default=0, help="seeds the crops, the start view and random")
    parser.add_argument("--out", default=None, help=f"output folder (default {DEFAULT_OUT}/<time>)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(message)s")
    args = build_parser().parse_args(argv)
    try:
        summary = run_active(args)
    except (FileNotFoundError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    for step in summary["steps"]:
        print(
            f"view {step['k']}: candidate {step['view']} (azimuth {step['azimuth']:.0f}, elevation "
            f"{step['elevation']:.0f}), latent var trace {step['trace']:.3f}, "
            f"IoU {step['iou']:.4f}, CD {step['cd']:.4f}, {step['seconds']:.1f} s"
        )
    print(f"{summary['strategy']} sequence of {summary['shape_id']} -> {summary['out']}")
    return 0


def run_active(args: argparse.Namespace) -> dict:
    """Run one sequence and write its files; returns the summary written to summary.json."""
    if args.views < 1:
        raise ValueError(f"--views must be >= 1, got {args.views}")
    source = f"{PREFIX}{args.model}" if args.model else args.checkpoint or args.run
    predictor = open_model(source, temperature=args.temperature, root=args.root)
    world_dir = args.world or predictor.world
    if world_dir is None:
        raise FileNotFoundError("the run names no data world (no run.json): pass --world <world folder>")
    world = open_world(world_dir)
    ids = world.shape_ids(args.split)
    shape_id = args.shape or (ids[0] if ids else None)
    if shape_id not in ids:
        raise ValueError(f"shape {shape_id!r} is not in the {args.split} split of {world.root}, e.g. {ids[:3]}")
    candidates = candidate_views(world, shape_id, args.candidates, args.azimuths, args.elevations)
    start = start_view(args.seed, shape_id, len(candidates)) if args.start is None else args.start
    encode = ViewEncoder(predictor, candidates, args.min_scale, args.seed)
    if args.refine_size < 1 or args.refine_iterations < 1:
        raise ValueError(
            f"--refine-size and --refine-iterations must be >= 1, got {args.refine_size}, {args.refine_iterations}"
        )
    context = SequenceContext(args.seed, None, None, predictor, args.refine_size, args.refine_iterations)
    context.observer = build_observer(args.observe, context, args.observer_dir)
    strategy = build_strategy(args.strategy, context, args.strategy_dir)
    observer = context.observer
    fusion = loop_fusion(predictor, observer)  # refined: the prior reconstruct.py refines, as Table A
    steps = active_reconstruction(
        candidates,
        encode,
        strategy,
        predictor.decoder,
        args.views,
        start,
        fusion=fusion,
        resolution=args.resolution,  # the mesh the strategy scores on is the one the figure and files show
        observe=observer,
    )
    out = Path(args.out) if args.out else DEFAULT_OUT / time.strftime("%Y-%m-%d_%H-%M-%S")
    surfaces = step_surfaces(steps, predictor.decoder, candidates, args.resolution)
    records = write_steps(steps, surfaces, predictor.decoder, world, candidates, encode, args.resolution, out)
    heading = f"{args.strategy} strategy, {shape_id}, crops of area [{args.min_scale:g}, 1]"
    inputs = [encode.input(s.view) for s in steps]
    ious = [r["iou"] for r in records]
    save_figure(sequence_figure(inputs, steps, surfaces, candidates, ious, heading), out / "sequence.png")
    report = sequence_page(out, steps, surfaces, candidates, inputs, records, heading)
    summary = {
        "shape_id": shape_id,
        "world": str(world.root),
        "checkpoint": str(predictor.checkpoint),
        "strategy": args.strategy,
        "observe": args.observe,
        "candidates": candidates.source,
        "n_candidates": len(candidates),
        "min_scale": args.min_scale,
        "seed": args.seed,
        "steps": records,
        "out": str(out),
        "report": str(report),
    }
    atomic.write_json(out / SUMMARY_FILE, summary)
    return summary


def sequence_page(out: Path, steps, surfaces, candidates, inputs, records: list[dict], heading: str) -> Path:
    """report.html with a slider over the views taken: at step k the mesh of the k views' fused code coloured
    by its std (one colour scale for all steps, so the std is seen to fall), and the k cameras taken."""
    stds = [None if s is None else np.sqrt(np.maximum(s.variance, 0.0)) for s in surfaces]
    drawn = [std for std in stds if std is not None and len(std)]
    top = colour_range(np.concatenate(drawn), None) if drawn else 1.0
    hw = candidates.image_hw
    scenes = []
    for k, (surface, std, record) in enumerate(zip(surfaces, stds, records), start=1):
        if surface is None:
            continue
        taken = [s.view for s in steps[:k]]
        cameras = [(candidates.K[v], candidates.world_to_cam[v], tuple(int(x) for x in hw[v])) for v in taken]
        figures = {key: record[key] for key in ("view", "azimuth", "elevation", "trace", "iou", "cd")}
        scenes.append(Scene(f"{k} view(s)", coloured_mesh(surface.mesh, std, top, DEFAULT_CMAP), cameras, figures))
    bar = out / "sequence_colourbar.png"
    write_colour_bar(bar, top)
    views = [image.permute(1, 2, 0).clamp(0, 1).numpy() for image in inputs]
    return write_report(out, heading, scenes, views, bar, slider=True)


def write_steps(
    steps, surfaces, decoder, world, candidates, encode: ViewEncoder, resolution: int, out: Path
) -> list[dict]:
    """Per step: the view as the encoder saw it (views/step_K.png), the mesh with its std (step_K.ply/.glb),
    and a record with the view's pose, the fused trace and the scores against the ground truth (NaN without it)."""
    scorer = Reconstructor(decoder, "active", world, resolution)
    has_truth = world.mesh_path(candidates.shape_id).is_file()
    angles = candidates.azimuth_elevation()
    records = []
    for k, (step, surface) in enumerate(zip(steps, surfaces), start=1):
        pixels = (encode.input(step.view).permute(1, 2, 0).clamp(0, 1).numpy() * 255).round().astype(np.uint8)
        with atomic.atomic_path(out / "views" / f"step_{k}.png") as tmp:
            Image.fromarray(pixels).save(tmp, format="PNG")
        scores = scorer.scores(step.mu, candidates.shape_id) if has_truth else {"iou": np.nan, "cd": np.nan}
        record = {
            "k": k,
            "view": step.view,
            "azimuth": float(angles[step.view, 0]),
            "elevation": float(angles[step.view, 1]),
            "trace": float(latent_trace(step.var)),
            "iou": float(scores["iou"]),
            "cd": float(scores["cd"]),
            "seconds": float(step.seconds),
            "fallback": step.fallback,
        }
        if surface is not None:
            std = np.sqrt(np.maximum(surface.variance, 0.0))
            record["mesh"] = write_mesh_files(surface.mesh, std, out, stem=f"step_{k}")["ply"]
        records.append(record)
    return records
