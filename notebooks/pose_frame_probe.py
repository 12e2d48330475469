"""Does the estimated pose leave the drawn shape off the training frame? pose_measure.py, each IoU also scored
after putting the drawn shape into the frame every training shape is in.

    PYTHONPATH=. python notebooks/pose_frame_probe.py MODEL OUT.jsonl --world W --views 1 --shapes 12

Every training shape of a voxel world is normalised as DeepSDF does (`mesh_sdf.unit_sphere_normalisation`): its
bounding box centred on the origin, its farthest surface point at 1 / 1.03. With the cameras known, the frame is
theirs; with the pose estimated from one view, a shape drawn larger and farther (or shifted, with the pose
shifted back) draws the same masks. This probe reads the drawn shape's surface (marching cubes of its SDF at 64^3
over the unit cube's [-1.1, 1.1]^3), measures its box centre c and its farthest point r from c, and scores the
SDF put back into the normalised frame, f(c + k x) / k with k = 1.03 r, beside the raw one. Each row gains
`<fused|known|pose>_iou_normalised` and the drawn frame `<...>_frame` = (c, 1.03 r).
Everything else is pose_measure.py's, arguments included.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch
from skimage.measure import marching_cubes

sys.path.insert(0, str(Path(__file__).resolve().parent))
import pose_measure  # noqa: E402

from ushape.data.real.mesh_sdf import UNIT_SPHERE_BUFFER  # noqa: E402
from ushape.decoder.query import code_sdf_fn  # noqa: E402
from ushape.metrics.voxel_iou import PROTOCOL_LEVEL, numpy_sdf, voxel_iou  # noqa: E402

GRID, EXTENT = 64, 1.1
SCORED: list[tuple[float, list[float], float]] = []
_iou, _shape_rows = pose_measure.iou, pose_measure.shape_rows


def drawn_frame(sdf) -> tuple[np.ndarray, float]:
    """(box centre [3], farthest surface point's distance from it) of the SDF's zero surface."""
    axis = np.linspace(-EXTENT, EXTENT, GRID, dtype=np.float32)
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    with torch.no_grad():
        values = torch.cat([sdf(torch.from_numpy(p)) for p in np.array_split(points, 16)]).numpy()
    verts, _, _, _ = marching_cubes(values.reshape(GRID, GRID, GRID), 0.0, spacing=(axis[1] - axis[0],) * 3)
    verts = verts - EXTENT
    centre = (verts.min(0) + verts.max(0)) / 2
    return centre, float(np.linalg.norm(verts - centre, axis=1).max())


def scored_iou(decoder, code, voxels, frame) -> float:
    raw = _iou(decoder, code, voxels, frame)
    sdf = code_sdf_fn(decoder, code)
    c, r = drawn_frame(sdf)
    k = UNIT_SPHERE_BUFFER * r
    shift = torch.as_tensor(c, dtype=torch.float32)

    def normalised(points: torch.Tensor) -> torch.Tensor:
        return sdf(shift + k * points) / k

    centre, scale, side = frame
    SCORED.append((voxel_iou(numpy_sdf(normalised), voxels, side, centre, scale, PROTOCOL_LEVEL), c.tolist(), k))
    return raw


def shape_rows(*args, **kwargs) -> list[dict]:
    SCORED.clear()
    rows = _shape_rows(*args, **kwargs)
    names = ("fused", "known", "pose")
    if len(SCORED) != len(names) * len(rows):
        raise SystemExit("pose_frame_probe reads the fused, known and pose IoUs in order: run it without --oracle")
    for i, row in enumerate(rows):
        for j, name in enumerate(names):
            value, c, k = SCORED[len(names) * i + j]
            row[f"{name}_iou_normalised"] = value
            row[f"{name}_frame"] = [round(x, 4) for x in c] + [round(k, 4)]
        print(
            "normalised", row["shape"], {n: round(row[f"{n}_iou_normalised"] - row[f"{n}_iou"], 3) for n in names},
            flush=True,
        )
    return rows


if __name__ == "__main__":
    pose_measure.iou = scored_iou
    pose_measure.shape_rows = shape_rows
    pose_measure.main()
