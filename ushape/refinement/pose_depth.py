"""What a depth map adds to the pose search (`pose_search`): where the object stands and how large it is, in the
depth's units (an RGB-D camera's frames with no camera in the object's frame).

The search's residuals read the depth through `joint.Problem` (each return divided by the pose's scale); here are
the start it gives the hypotheses (`depth_placed`) and the screening of depth maps that cannot be read
(`usable_depth`).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ushape.refinement.pose import Pose
from ushape.refinement.posterior import RefineSettings
from ushape.refinement.views import ObservedView, mask_box, screen_view


def depth_placed(pose: Pose, view: ObservedView, cam_from_ref: np.ndarray, points: np.ndarray, cells: int = 12) -> Pose:
    """The placed pose scaled about the view's camera centre (its silhouette unchanged) so that the code's points
    nearest the camera sit at the depth the view's returns read: the object's distance and size in the depth
    map's units. Nearest depths are compared per cell of a cells x cells grid over the mask's box (the median
    ratio over the cells both cover); a view with no usable return keeps the pose."""
    if view.depth is None:
        return pose
    K = np.asarray(view.K, dtype=np.float64)
    u0, v0, u1, v1 = mask_box(view)
    cam = pose.object_camera(cam_from_ref)
    x = points @ cam[:3, :3].T + cam[:3, 3]  # object units, in the view's camera
    x = x[x[:, 2] > 1e-3]
    uv = (x @ K.T)[:, :2] / x[:, 2:3]

    def nearest(u: np.ndarray, v: np.ndarray, z: np.ndarray) -> np.ndarray:  # [cells * cells], inf where empty
        cu = np.floor((u - u0) / max(u1 - u0, 1e-6) * cells).astype(int)
        cv = np.floor((v - v0) / max(v1 - v0, 1e-6) * cells).astype(int)
        keep = (cu >= 0) & (cu < cells) & (cv >= 0) & (cv < cells)
        out = np.full(cells * cells, np.inf)
        np.minimum.at(out, cv[keep] * cells + cu[keep], z[keep])
        return out

    depth = view.depth.double().numpy()
    returns = (depth > 0) & (view.mask.numpy() > 0.5) & view.seen().numpy()
    rows, cols = np.nonzero(returns)
    observed = nearest(cols + 0.5, rows + 0.5, depth[rows, cols])
    predicted = nearest(uv[:, 0], uv[:, 1], x[:, 2] * pose.scale)  # in the camera's units
    both = np.isfinite(observed) & np.isfinite(predicted)
    if not both.any():
        return pose
    k = float(np.median(observed[both] / predicted[both]))
    eye = -cam_from_ref[:3, :3].T @ cam_from_ref[:3, 3]  # the view's camera centre in the reference frame
    return Pose(pose.R, eye + k * (pose.t - eye), pose.scale * k)


def usable_depth(
    views: Sequence[ObservedView], settings: RefineSettings
) -> tuple[list[ObservedView], list[str | None]]:
    """With mode depth, each view with its depth map where it holds finite returns, else its mask alone, and why
    (`views.screen_view`'s note; None where nothing was dropped). Other modes: the views as they are."""
    if settings.mode != "depth":
        return list(views), [None] * len(views)
    screened = [screen_view(v, use_depth=True) for v in views]
    return [s.view for s in screened], [s.fallback for s in screened]
