"""How much of a shape its masks determine: the visual hull of n views, scored like a decoder's shape.

    PYTHONPATH=. python notebooks/mask_hull.py WORLD [--shapes 30] [--views 1 3 6 12 24] [--split test]

For each shape of the r2n2 world WORLD, R2N2's 32^3 voxel grid is carved by the masks of n views spread around
the orbit (pretrained_measure.py's choice, the world's true cameras): a voxel stays where its centre, or (the
"dilated" column, like the +0.4 voxel level the decoders are scored at) any of the 27 points at -0.4, 0, +0.4
voxel widths along each axis around it, projects inside every mask. The hull is the largest shape those masks
allow, so its IoU with the voxels says how far masks alone can take refinement, and whether what the masks
leave open (hollows no view's outline reaches) is what a refined shape gets wrong.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pretrained_measure import spread  # noqa: E402
from r2n2_ceiling import shape_frame  # noqa: E402

from ushape.data.cameras import project  # noqa: E402
from ushape.data.layout import WorldIndex  # noqa: E402
from ushape.data.real.r2n2_voxels import read_r2n2_voxels  # noqa: E402
from ushape.metrics.reconstruction import iou_from_occupancy  # noqa: E402
from ushape.metrics.voxel_iou import voxel_centres_in_frame  # noqa: E402
from ushape.refinement.views import ObservedView, world_views  # noqa: E402

OFFSETS = np.array([(a, b, c) for a in (-0.4, 0, 0.4) for b in (-0.4, 0, 0.4) for c in (-0.4, 0, 0.4)])


def inside_masks(points: np.ndarray, views: list[ObservedView]) -> np.ndarray:
    """Bool [P]: points [P, 3] (world frame) that project inside the mask (> 0.5) of every view."""
    keep = np.ones(len(points), dtype=bool)
    for view in views:
        uv, z = project(points, np.asarray(view.K, dtype=np.float64), np.asarray(view.world_to_cam, np.float64))
        h, w = view.image_hw
        front = z > 0  # points behind the camera (or at its depth 0) are outside its mask
        col, row = np.full(len(points), -1), np.full(len(points), -1)
        col[front], row[front] = np.floor(uv[front, 0]).astype(int), np.floor(uv[front, 1]).astype(int)
        on = (col >= 0) & (col < w) & (row >= 0) & (row < h)
        mask = view.mask.numpy() > 0.5
        hit = np.zeros(len(points), dtype=bool)
        hit[on] = mask[row[on], col[on]]
        keep &= hit
    return keep


def hull_ious(world: WorldIndex, shape_id: str, counts: list[int]) -> dict[int, tuple[float, float]]:
    """{n views: (IoU of the centres' hull, IoU of the dilated hull)} against the shape's R2N2 voxels."""
    centre, scale, side, source = shape_frame(world, shape_id)
    voxels = read_r2n2_voxels(source)[0]
    n = voxels.shape[0]
    centres = voxel_centres_in_frame(side, n, centre, scale)
    width = side / n * scale
    points = (centres[:, None, :] + OFFSETS[None] * width).reshape(-1, 3)
    everything = world_views(world.views_path(shape_id), None, with_depth=False)
    out = {}
    for count in counts:
        views = [everything[i] for i in spread(count, len(everything))]
        at_centres = inside_masks(centres, views).reshape(n, n, n)
        dilated = inside_masks(points, views).reshape(-1, len(OFFSETS)).any(axis=1).reshape(n, n, n)
        out[count] = (iou_from_occupancy(at_centres, voxels), iou_from_occupancy(dilated, voxels))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("world")
    parser.add_argument("--shapes", type=int, default=30)
    parser.add_argument("--views", type=int, nargs="+", default=[1, 3, 6, 12, 24])
    parser.add_argument("--split", default="test")
    args = parser.parse_args()
    world = WorldIndex.load(args.world)
    rows = [hull_ious(world, s, args.views) for s in world.shape_ids(args.split)[: args.shapes]]
    print(f"{len(rows)} {args.split} shapes of {args.world}: visual hull IoU with the voxels (mean, median)")
    for count in args.views:
        centres = np.array([r[count][0] for r in rows])
        dilated = np.array([r[count][1] for r in rows])
        print(f"{count:3d} views: centres {centres.mean():.3f} ({np.median(centres):.3f}), "
              f"dilated {dilated.mean():.3f} ({np.median(dilated):.3f})")  # fmt: skip


if __name__ == "__main__":
    main()
