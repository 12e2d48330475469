"""Measure the real-mesh SDF signs: known-answer meshes, agreement with official voxels, time per mesh.

    ushape sign-bench --real-root ../shared/data/real_sample \
        [--baseline old_mesh_sdf.py [--baseline-signs old_mesh_signs.py]] [--samples 30000] \
        [--timing-samples 250000] [--json out.json]

`--baseline` names another version of ushape/data/real/mesh_sdf.py (e.g. `git show <commit>:ushape/data/real/mesh_sdf.py
> old.py`), measured on the same samples beside the current one; `--baseline-signs` the
mesh_signs.py it imports, when that differs from the current one. Prints markdown tables; the
measured numbers are in docs/mesh_sdf_signs.md.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import time
from pathlib import Path
from types import ModuleType
from typing import Any, Optional

import igl
import numpy as np

from ushape.data.real import mesh_sdf, mesh_signs, sign_cases
from ushape.data.real.pix3d import load_voxels, voxel_to_model
from ushape.data.real.voxel_check import has_interior, read_solid_binvox, tolerant_truth
from ushape.data.sampling import sample_points

AWAY = 0.01  # known-answer meshes: only samples at least this far from the surface count (unit-sphere frame)
TIMING_CHAIR = "ShapeNetCore.v2/03001627/1a6f615e8b1b5ae4dbbc9440457e303e/models/model_normalized.obj"
TIMING_LARGE = "pix3d/model/chair/IKEA_IVAR/model.obj"


def load_module(path: str | Path, signs: Optional[Path] = None) -> ModuleType:
    """Another mesh_sdf.py as a module; with `signs`, its `ushape.data.real.mesh_signs` import gets that file."""
    spec = importlib.util.spec_from_file_location("baseline_mesh_sdf", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up by name
    name = "ushape.data.real.mesh_signs"
    current = sys.modules.get(name)
    try:
        if signs is not None:
            signs_spec = importlib.util.spec_from_file_location("baseline_mesh_signs", signs)
            sys.modules[name] = sys.modules[signs_spec.name] = importlib.util.module_from_spec(signs_spec)
            signs_spec.loader.exec_module(sys.modules[name])
        spec.loader.exec_module(module)
    finally:
        if current is not None:
            sys.modules[name] = current
    return module


def inside_of(module: ModuleType, mesh, points: np.ndarray, options: dict) -> tuple[np.ndarray, Any]:
    """(bool [N] inside test of a mesh_sdf version, never rejecting (so every case gets a number), its MeshSdf).

    `options` (MeshSigns settings such as the resolution) go to the current version only."""
    if module is mesh_sdf:
        sdf = module.MeshSdf(mesh, **options)
    elif hasattr(module, "SignReport"):
        sdf = module.MeshSdf(mesh)
    else:
        sdf = module.MeshSdf(mesh, max_ambiguous_fraction=1.0)
    return sdf.inside(points), sdf


def known_answer_rows(methods: dict[str, ModuleType], n: int, options: dict) -> list[dict[str, Any]]:
    """Per known-answer mesh: share of right signs away from the surface, and near it (1e-4 to AWAY)."""
    rows = []
    for make in sign_cases.KNOWN_ANSWER_CASES + (sign_cases.open_box,):
        case = make()
        points = sample_points(case.mesh, n, np.random.default_rng(0))
        vertices, faces = np.asarray(case.mesh.vertices, np.float64), np.asarray(case.mesh.faces, np.int64)
        distance = np.sqrt(igl.point_mesh_squared_distance(points, vertices, faces)[0])
        away, near = distance >= AWAY, (distance > 1e-4) & (distance < AWAY)
        row: dict[str, Any] = {"case": case.name, "faces": len(faces), "samples away": int(away.sum())}
        for name, module in methods.items():
            inside, sdf = inside_of(module, case.mesh, points, options)
            row[name] = float(np.mean(inside[away] == case.solid(points[away]))) if case.solid else None
            row[f"{name} near"] = float(np.mean(inside[near] == case.solid(points[near]))) if case.solid else None
            if module is mesh_sdf:
                row.update(_report_columns(mesh_sdf.SignReport.of(sdf.signs)))
        rows.append(row)
    return rows


def real_models(root: Path) -> list[tuple[str, Path, Path]]:
    """(name, model file, voxel file) of every ShapeNetCore.v2 and Pix3D model under root."""
    found = [
        (p.parents[1].name, p, p.parent / "model_normalized.solid.binvox")
        for p in sorted(root.glob("ShapeNetCore.v2/*/*/models/model_normalized.obj"))
    ]
    found += [
        (f"{p.parent.parent.name}/{p.parent.name}", p, p.parent / "voxel.mat")
        for p in sorted(root.glob("pix3d/model/*/*/model.obj"))
    ]
    return [f for f in found if f[2].is_file()]


def real_rows(methods: dict[str, ModuleType], root: Path, n: int, options: dict) -> list[dict[str, Any]]:
    rows = []
    for name, model, voxels in real_models(root):
        raw = mesh_sdf.load_mesh(model)
        if voxels.suffix == ".mat":
            occupancy = load_voxels(voxels)
            index_to_model = voxel_to_model(raw, occupancy.shape[0])
        else:
            occupancy, index_to_model = read_solid_binvox(voxels)
        mesh, centre, scale = mesh_sdf.normalise_mesh(raw)
        row: dict[str, Any] = {"model": name, "faces": len(raw.faces), "solid voxels": has_interior(occupancy)}
        for method, module in methods.items():
            rng = np.random.default_rng(0)
            start = time.perf_counter()
            try:
                extra = options if module is mesh_sdf else {}
                result = module.sample_mesh_sdf(mesh, n, rng, min_inside_fraction=0.0, min_confidence=0.0, **extra)
            except module.MeshProcessingError as err:
                row[method] = None
                row[f"{method} rejected"] = str(err)
                continue
            row[f"{method} s"] = round(time.perf_counter() - start, 2)
            samples, report = result if isinstance(result, tuple) else (result, None)
            rows_xyz = np.concatenate([samples["pos"], samples["neg"]]).astype(np.float64)
            checked, truth = tolerant_truth(occupancy, index_to_model, rows_xyz[:, :3] / scale + centre)
            row["checked"] = int(checked.sum())
            row[method] = float(np.mean((rows_xyz[checked, 3] < 0) == truth[checked]))
            if module is mesh_sdf:
                row.update(_report_columns(report))
        rows.append(row)
    return rows


def _report_columns(report) -> dict[str, Any]:
    return {
        "confidence": report.confidence,
        "resolution agreement": report.resolution_agreement,
        "winding agreement": report.winding_agreement,
        "near": report.near,
        "enclosed": report.enclosed,
    }


def timing_rows(methods: dict[str, ModuleType], root: Path, n: int, repeats: int) -> list[dict[str, Any]]:
    chair = mesh_sdf.normalise_mesh(mesh_sdf.load_mesh(root / TIMING_CHAIR))[0].subdivide()
    large = mesh_sdf.normalise_mesh(mesh_sdf.load_mesh(root / TIMING_LARGE))[0]
    for _ in range(4):
        large = large.subdivide()
    rows = []
    for label, mesh in (("ShapeNet chair 1a6f615e, subdivided once", chair), ("Pix3D IKEA_IVAR, subdivided 4x", large)):
        points = sample_points(mesh, n, np.random.default_rng(0))
        row: dict[str, Any] = {"mesh": label, "faces": len(mesh.faces), "samples": n}
        best = {m: np.inf for m in methods}
        for _ in range(repeats):  # interleaved, so both see the same machine load
            for method, module in methods.items():
                start = time.perf_counter()
                module.MeshSdf(mesh).sdf(points)
                best[method] = min(best[method], time.perf_counter() - start)
        row.update({f"{m} s": round(t, 2) for m, t in best.items()})
        row["load average"] = os.getloadavg()[0]
        rows.append(row)
    return rows


def markdown(rows: list[dict[str, Any]]) -> str:
    keys = list(dict.fromkeys(k for row in rows for k in row))
    cell = lambda v: "-" if v is None else f"{v:.4f}" if isinstance(v, float) else str(v)  # noqa: E731
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(cell(row.get(k)) for k in keys) + " |" for row in rows]
    return "\n".join(lines)


def main(argv: Optional[list[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--real-root", type=Path, help="folder holding ShapeNetCore.v2/ and pix3d/model/")
    parser.add_argument("--baseline", type=Path, help="another mesh_sdf.py to measure beside the current one")
    parser.add_argument("--baseline-signs", type=Path, help="the mesh_signs.py the baseline imports")
    parser.add_argument("--samples", type=int, default=30_000)
    parser.add_argument("--resolution", type=int, default=mesh_signs.RESOLUTION, help="the current method's grid")
    parser.add_argument("--check-resolution", type=int, default=mesh_signs.CHECK_RESOLUTION)
    parser.add_argument("--timing-samples", type=int, default=250_000)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--no-timing", action="store_true")
    parser.add_argument("--json", type=Path, help="also write every number here")
    args = parser.parse_args(argv)
    methods = {"current": mesh_sdf}
    if args.baseline:
        methods["baseline"] = load_module(args.baseline, args.baseline_signs)
    options = {"resolution": args.resolution, "check_resolution": args.check_resolution}
    results: dict[str, Any] = {"known answers": known_answer_rows(methods, args.samples, options)}
    print(f"## Known-answer meshes (share of right signs, samples >= {AWAY} from the surface; near: 1e-4 to {AWAY})\n")
    print(markdown(results["known answers"]), flush=True)
    if args.real_root:
        results["real models"] = real_rows(methods, args.real_root, args.samples, options)
        print("\n## Real models against official voxels (tolerant check)\n")
        print(markdown(results["real models"]), flush=True)
        if not args.no_timing:
            results["timing"] = timing_rows(methods, args.real_root, args.timing_samples, args.repeats)
            print(
                f"\n## Time per mesh, MeshSdf construction + sdf of {args.timing_samples} samples "
                f"(best of {args.repeats})\n"
            )
            print(markdown(results["timing"]), flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0
