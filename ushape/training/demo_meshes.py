"""After stage 2, a held-out shape reconstructed with its uncertainty: a run ends with meshes to look at.

For each of the first `shapes` validation shapes, `reconstruct` (the same pipeline as reconstruct.py)
runs once on its first view and once on all its views fused (the `fusion` group's rule, Bayesian by
default; where `reconstruct.py --fit-temperature` has fitted the run's shared error, Bayesian(-K) becomes
the calibrated `shared`(-K) rule: the same views and mean, a variance that keeps what the views share),
both coloured on the single view's scale so the two can be compared by eye:

    <run>/meshes/<shape id>_1view/     mesh.ply, mesh.glb, overview.png, depth_00.png, summary.json
    <run>/meshes/<shape id>_<N>views/
    <run>/meshes/<shape id>_1view_refined_<mode>/, ..._<N>views_refined_<mode>/   the same views, the fused
                                       code refined on their masks (refine "masks") or masks + depth ("depth")
    <run>/meshes/<shape id>_1view_refined_masks_pose/   with refine "masks": the first view refined with its
                                       camera hidden, the object's pose estimated with the shape (docs/pose.md)
    <run>/meshes/scores.json           each mesh's IoU / Chamfer against the ground truth, and those of
                                       the shape's own stage-1 code (what this decoder can do at best)

The scores follow the Pix3D protocol of `eval.py` (32^3 voxels, 1024 surface points) on the demo's
own meshes, so they can differ a little from `eval.py`'s, which meshes at its own resolution.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path
from typing import Callable

import numpy as np
import torch
import trimesh
from torch import Tensor

from ushape import atomic
from ushape.data.augment import read_image
from ushape.data.layout import WorldIndex
from ushape.data.rendering import on_white
from ushape.decoder.artifacts import CodeTable
from ushape.decoder.query import code_sdf_fn, frozen
from ushape.encoder.datamodule import view_files
from ushape.fusion import FusedCode
from ushape.mesh.extraction import EmptySurfaceError, extract_mesh
from ushape.metrics.pix3d import ShapeReference, pix3d_metrics, reference_from_mesh
from ushape.reconstruction.calibrated_fusion import calibrated_counterpart
from ushape.reconstruction.export import DEFAULT_CMAP, coloured_mesh, read_ply_std, write_colour_bar
from ushape.reconstruction.pipeline import reconstruct
from ushape.reconstruction.predictor import load_predictor
from ushape.reconstruction.report_page import Scene, write_report
from ushape.reconstruction.settings import ReconstructionSettings
from ushape.refinement.pose import rotation_angle_deg
from ushape.workspace import SCORES_FILE, SUMMARY_FILE

log = logging.getLogger(__name__)
EMPTY_NOTE = "empty_surface.txt"

OWN_CODE = "own_code"
FusionRule = Callable[[Tensor, Tensor], FusedCode]  # (mu [V, D], var [V, D]) -> fused Gaussian


POSE_CASE = "masks_pose"  # the folder suffix of the case refined with its camera hidden


def write_demo_meshes(
    checkpoint: str | Path,
    world: WorldIndex,
    out_dir: str | Path,
    shapes: int = 1,
    resolution: int = 96,
    split: str = "val",
    fusion: FusionRule | None = None,
    codes: CodeTable | None = None,
    refine: str | None = None,
) -> Path | None:
    """Reconstruct `shapes` held-out shapes from 1 and from all views into out_dir; None if shapes = 0.

    A code with no surface (an undertrained encoder) leaves an `empty_surface.txt` saying so, not a crash.
    With the split's stage-1 `codes`, scores.json also holds each shape's own code's scores.
    """
    ids = world.shape_ids(split)[:shapes]
    if shapes <= 0 or not ids:
        return None
    predictor = load_predictor(checkpoint)
    fusion = calibrated_counterpart(fusion, predictor)
    out_dir = Path(out_dir)
    for shape_id in ids:
        views = view_files(world.root, shape_id)
        settings = ReconstructionSettings(resolution=resolution, depth_size=48)
        modes = (None,) if refine is None else (None, refine)
        cases = [(inputs, mode) for inputs in (views[:1], views) for mode in modes]
        if refine == "masks":  # and one view with its camera hidden: the pose estimated with the shape
            cases.insert(2, (views[:1], POSE_CASE))
        for inputs, mode in cases:
            folder = out_dir / f"{shape_id}_{len(inputs)}view{'s' if len(inputs) > 1 else ''}"
            folder = folder.with_name(f"{folder.name}_refined_{mode}") if mode else folder
            try:
                mode_settings = dataclasses.replace(settings, refine=mode)
                if mode == POSE_CASE:
                    mode_settings = dataclasses.replace(settings, refine="masks", pose="estimate")
                summary = reconstruct(predictor, inputs, fusion, folder, mode_settings)
            except EmptySurfaceError as err:
                log.warning("no mesh for %s from %d view(s): %s", shape_id, len(inputs), err)
                folder.mkdir(parents=True, exist_ok=True)
                atomic.write_text(folder / EMPTY_NOTE, f"The fused code's SDF has no zero crossing: {err}\n")
                continue
            # The single view's colour scale for the others too: less uncertainty looks darker.
            if settings.std_max is None:
                settings = dataclasses.replace(settings, std_max=float(summary["files"]["std_max"]))
    scores = score_demo(predictor.decoder, world, out_dir, ids, resolution, codes)
    atomic.write_json(out_dir / SCORES_FILE, scores)
    demo_page(out_dir, world, ids[0], scores.get(ids[0], {}))
    return out_dir


def demo_page(out_dir: Path, world: WorldIndex, shape_id: str, scores: dict[str, dict[str, float]]) -> Path | None:
    """out_dir/report.html: the first demo shape from one view and from all, fused and refined, on the single
    view's colour scale, with the views' cameras and each mesh's scores; None when no demo has a mesh."""
    folders = sorted(
        (f for f in out_dir.glob(f"{shape_id}_*view*") if (f / SUMMARY_FILE).is_file()),
        key=lambda f: (len(json.loads((f / SUMMARY_FILE).read_text())["views"]), "refined" in f.name),
    )
    if not folders:
        return None
    with np.load(world.views_path(shape_id)) as views:
        Ks, w2cs = views["K"].astype(np.float64), views["world_to_cam"].astype(np.float64)
    side = int(round(2 * Ks[0, 0, 2]))
    top = float(json.loads((folders[0] / SUMMARY_FILE).read_text())["files"]["std_max"])
    scenes = []
    for folder in folders:
        summary = json.loads((folder / SUMMARY_FILE).read_text())
        n = len(summary["views"])
        mesh = trimesh.load(folder / "mesh.ply", process=False)
        label = f"{n} view{'s' if n > 1 else ''}, " + ("refined" if "refined" in folder.name else "fused")
        figures = {"latent trace (fused)": summary["fused"]["trace_var"], **scores.get(folder.name, {})}
        cameras = [(Ks[i], w2cs[i], (side, side)) for i in range(min(n, len(Ks)))]
        pose = (summary.get("refinement") or {}).get("pose")
        if pose:  # the cameras where the estimate put them, and how sure it is
            label += ", pose estimated"
            cameras = [(Ks[i], np.asarray(c), (side, side)) for i, c in enumerate(pose["cameras"])]
            figures["rotation std (deg)"] = pose["groups"][0]["rotation_std_deg"]
            figures["rotation error (deg)"] = rotation_angle_deg(
                np.asarray(pose["cameras"][0])[:3, :3], w2cs[0][:3, :3]
            )
        scenes.append(
            Scene(label, coloured_mesh(mesh, read_ply_std(folder / "mesh.ply"), top, DEFAULT_CMAP), cameras, figures)
        )
    bar = out_dir / "demo_colourbar.png"
    write_colour_bar(bar, top)
    own = scores.get(OWN_CODE) or {}
    figures = {"shape": shape_id, **{f"own code {k}": v for k, v in own.items()}}
    # The views as a render is seen: over white (data.rendering's rule, in 8 bits), in [0, 1] for the thumbnails.
    views = [
        on_white(np.round(read_image(path) * 255).astype(np.uint8)) / 255.0 for path in view_files(world.root, shape_id)
    ]
    return write_report(
        out_dir, f"held-out {shape_id}: one view and all, fused and refined", scenes, views, bar, figures=figures
    )


def score_demo(
    decoder, world: WorldIndex, meshes_dir: Path, shape_ids: list[str], resolution: int, codes: CodeTable | None
) -> dict[str, dict[str, dict[str, float]]]:
    """{shape id: {demo folder or "own_code": {"iou", "cd"}}} against each shape's ground-truth mesh."""
    scores = {}
    for shape_id in shape_ids:
        if not world.mesh_path(shape_id).is_file():
            log.warning("no ground-truth mesh %s: the demo of %s is not scored", world.mesh_path(shape_id), shape_id)
            continue
        reference = reference_from_mesh(trimesh.load(world.mesh_path(shape_id), process=False))
        shape_scores = {}
        for folder in sorted(meshes_dir.glob(f"{shape_id}_*view*")):
            record = folder / SUMMARY_FILE
            if record.is_file():
                summary = json.loads(record.read_text())
                mesh = trimesh.load(folder / "mesh.ply", process=False)
                code = torch.tensor((summary.get("refinement") or summary["fused"])["mu"])
                shape_scores[folder.name] = _code_scores(decoder, code, reference, mesh)
        if codes is not None and shape_id in codes.shape_ids:
            try:
                shape_scores[OWN_CODE] = _code_scores(decoder, codes.lookup(shape_id), reference, None, resolution)
            except EmptySurfaceError:
                shape_scores[OWN_CODE] = {"iou": 0.0, "cd": float("nan")}
        scores[shape_id] = shape_scores
    return scores


def _code_scores(
    decoder, code: Tensor, reference: ShapeReference, mesh: trimesh.Trimesh | None, resolution: int = 96
) -> dict[str, float]:
    """IoU and Chamfer of the code's surface (`mesh`, else extracted) against the reference."""
    with frozen(decoder):
        sdf = code_sdf_fn(decoder, code)
        if mesh is None:
            mesh, _ = extract_mesh(sdf, resolution)

        def inside(points: np.ndarray) -> np.ndarray:
            return (sdf(torch.as_tensor(points, dtype=torch.float32)) < 0).numpy()

        return pix3d_metrics(mesh, inside, reference, emd=False)


def demo_digest(meshes_dir: str | Path) -> list[dict]:
    """Per demo reconstruction: its folder name, views fused, latent covariance trace, mean vertex std,
    overview picture, IoU / Chamfer and those of the shape's own code where scored; or the empty-surface
    note. What a run prints at its end."""
    rows = []
    scores_path = Path(meshes_dir) / SCORES_FILE
    scores = json.loads(scores_path.read_text()) if scores_path.is_file() else {}
    by_folder = {name: (shape, s) for shape, per in scores.items() for name, s in per.items() if name != OWN_CODE}
    for folder in sorted(p for p in Path(meshes_dir).iterdir() if p.is_dir()):
        record = folder / SUMMARY_FILE
        if not record.is_file():
            rows.append({"name": folder.name, "empty": True})
            continue
        summary = json.loads(record.read_text())
        rows.append(
            {
                "name": folder.name,
                "views": len(summary["views"]),
                "trace": summary["fused"]["trace_var"],
                "std_mean": summary["mesh"]["std_mean"],
                "overview": summary["files"]["overview"],
                "fusion": summary.get("fusion"),
                "fusion_calibration": summary.get("fusion_calibration"),
            }
        )
        if folder.name in by_folder:
            shape, found = by_folder[folder.name]
            rows[-1].update(iou=found["iou"], cd=found["cd"], own_code=scores[shape].get(OWN_CODE))
    return sorted(rows, key=lambda row: (row.get("views", 0), row["name"]))  # one view first, then all
