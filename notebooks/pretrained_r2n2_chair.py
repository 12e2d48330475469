"""A real-shape model on the shared 3D-R2N2 chair's own 24 renders, through `reconstruct.py` as a user runs it.

    PYTHONPATH=. python notebooks/pretrained_r2n2_chair.py MODEL [--cases 1,3,24] [--out outputs/r2n2_chair_model]

MODEL is `pretrained:<name>` or a run folder. For each case (views 00; 00, 08, 16; all 24) it runs
`reconstruct.py <renders> --model/--run MODEL --refine masks` (the cameras from rendering_metadata.txt, in
R2N2's frame placed by the model's typical frame: the chair itself is unseen), then scores the fused and the
refined code (summary.json's `fused.mu` and `refinement.mu`) against the chair's R2N2 voxels, IoU at 32^3 at
the level docs/pretrained.md chose (+0.4 voxel), in the chair's own frame (its voxel surface normalised as
the r2n2 world normalises every shape). Prints and writes OUT/results.json; seconds per case from the run.

--pose-estimate hides the cameras' placement: `--pose estimate` (each image's K kept), the views of a case
sharing one pose through `--relative-poses` (their rows' cameras in R2N2's own frame: only their motion between
each other is used); the rotation error is the estimated camera's against the metadata's.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from ushape.data.cameras import metadata_to_cameras, parse_metadata
from ushape.data.real import r2n2_voxels
from ushape.data.real.mesh_sdf import normalise_mesh
from ushape.decoder.query import code_sdf_fn
from ushape.metrics.voxel_iou import PROTOCOL_LEVEL, numpy_sdf, voxel_iou
from ushape.reconstruction.pretrained import PREFIX, open_model
from ushape.refinement.pose import rotation_angle_deg

CHAIR = ("03001627", "1a6f615e8b1b5ae4dbbc9440457e303e")


def chair_frame(voxel_file: Path):
    """(voxels, side, centre, scale): the chair's voxels and its frame as the r2n2 world normalises a shape."""
    voxels, side = r2n2_voxels.read_r2n2_voxels(voxel_file)
    _, centre, scale = normalise_mesh(r2n2_voxels.voxel_surface(voxels, side))
    return voxels, side, centre, scale


def iou(decoder, mu, frame) -> float:
    voxels, side, centre, scale = frame
    values = numpy_sdf(code_sdf_fn(decoder, torch.tensor(mu, dtype=torch.float32)))
    return voxel_iou(values, voxels, side, centre, scale, PROTOCOL_LEVEL)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model")
    parser.add_argument("--sample", default="../shared/data/real_sample")
    parser.add_argument("--voxels", default="../shared/data/ShapeNetVox32")
    parser.add_argument("--cases", default="1,3,24")
    parser.add_argument("--out", type=Path, default=Path("outputs/r2n2_chair_model"))
    parser.add_argument("--pose-estimate", action="store_true", help="hide the cameras' placement (docstring)")
    args = parser.parse_args()
    renders = Path(args.sample) / "ShapeNetRendering" / CHAIR[0] / CHAIR[1] / "rendering"
    frame = chair_frame(Path(args.voxels) / CHAIR[0] / CHAIR[1] / "model.binvox")
    decoder = open_model(args.model).decoder
    source = ["--model", args.model[len(PREFIX) :]] if args.model.startswith(PREFIX) else ["--run", args.model]
    results = []
    for n in map(int, args.cases.split(",")):
        views = sorted({round(i * 24 / n) % 24 for i in range(n)})
        out = args.out / f"{n}_views"
        started = time.perf_counter()
        command = [sys.executable, "reconstruct.py", *(str(renders / f"{v:02d}.png") for v in views), *source]
        rows = parse_metadata((renders / "rendering_metadata.txt").read_text())[views]
        _, cameras = metadata_to_cameras(rows, 137)
        if args.pose_estimate:
            out.mkdir(parents=True, exist_ok=True)
            np.savez(out.parent / f"{n}_relative.npz", world_to_cam=cameras)
            command += ["--pose", "estimate"] + (["--relative-poses", str(out.parent / f"{n}_relative.npz")] * (n > 1))
            out = out.with_name(f"{n}_views_pose")
        subprocess.run([*command, "--refine", "masks", "--out", str(out)], check=True)
        wall = time.perf_counter() - started
        summary = json.loads((out / "summary.json").read_text())
        refined = summary["refinement"]
        row = {
            "views": views,
            "fused_iou": iou(decoder, summary["fused"]["mu"], frame),
            "refined_iou": iou(decoder, refined["mu"], frame) if refined and refined.get("mu") else None,
            "fallback": refined.get("fallback") if refined else "no refinement",
            "wall_seconds": round(wall, 1),
            "seconds": summary["seconds"],
        }
        if refined and refined.get("pose"):
            estimated = np.asarray(refined["pose"]["cameras"][0])
            group = refined["pose"]["groups"][0]
            row["rotation_error_deg"] = rotation_angle_deg(estimated[:3, :3], cameras[0][:3, :3])
            row["rotation_std_deg"] = group["rotation_std_deg"]
            row["ambiguous"] = group["ambiguous"]
        keys = ("views", "fused_iou", "refined_iou", "fallback", "wall_seconds", "rotation_error_deg", "ambiguous")
        print(json.dumps({k: row[k] for k in keys if k in row}))
        results.append(row)
    args.out.mkdir(parents=True, exist_ok=True)
    name = "results_pose.json" if args.pose_estimate else "results.json"
    (args.out / name).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
