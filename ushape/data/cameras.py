"""Pinhole cameras of the ShapeNetRendering (3D-R2N2) protocol.

Protocol (3D-R2N2's Blender script, as documented by later users such as DISN's
`getBlenderProj`): per view, azimuth U[0, 360), elevation U[25, 30), in-plane rotation 0,
distance = distance_ratio * 1.75 with distance_ratio U[0.65, 0.95), Blender's default
35 mm lens on a 32 mm sensor, i.e. a horizontal field of view of 2*atan(16/35) = 49.13 deg.
The camera looks at the object's centre with world up = +y. `rendering_metadata.txt`
holds one row per view: "az el inplane dist_ratio fov".

Conventions used throughout ushape:
- World frame: the shape's normalised frame, y up. In ShapeNetCore v1's axes (the frame R2N2
  rendered in; ushape's synthetic shapes, which face +z, take the same rows in their own axes)
  a view at distance d sits at
  d (cos el cos az, sin el, +cos el sin az) from the object's centre: R2N2's Blender script
  turns its camera rig by -azimuth about Blender's up axis, so the azimuth grows from +x
  towards +z (clockwise seen from above). Checked against R2N2's real renders of a chair
  (tests/data/real/test_real_shapenet_rendering.py: silhouette IoU >= 0.95 on every view).
- ShapeNetCore v2 turned every model 90 degrees about y relative to v1 (v1 models face +x,
  v2 models face -z): (x, y, z)_v2 = (z, y, -x)_v1. `frame="v2"` expresses the same camera in
  a v2 model's axes (`FRAME_FROM_V1`), so R2N2's rows frame a v2 mesh as they framed its v1 twin.
- Camera frame: OpenCV, x right, y down, z forward. `world_to_cam` [4,4] maps homogeneous
  world points to camera coordinates; depth is the camera z coordinate.
- Pixels: u to the right, v down; pixel (row i, col j) covers [j, j+1) x [i, i+1), so its
  centre is (j + 0.5, i + 0.5) and the principal point (W/2, H/2) is the image centre.
- Field of view spans the larger image side (Blender's automatic sensor fit).
- R2N2 normalised ShapeNet v1 objects to a unit bounding-box diagonal, centred at the box
  centre; DeepSDF's frame is larger (unit sphere). `r2n2_centre`/`r2n2_scale` give the
  object's box centre and the factor mapping our frame into R2N2's (p_r2n2 = (p - centre) *
  scale), so the same metadata rows frame the object exactly as R2N2's renders did.
- The fifth metadata column: R2N2's files store 25 there, which is not the lens Blender
  rendered with, so `metadata_to_cameras` uses `R2N2_FOV_DEG` unless told otherwise. Files
  written by ushape store the field of view actually used (49.13).
"""

from __future__ import annotations

import math
from typing import Sequence, Union

import numpy as np

BLENDER_LENS_MM = 35.0
BLENDER_SENSOR_MM = 32.0
R2N2_FOV_DEG = math.degrees(2.0 * math.atan(BLENDER_SENSOR_MM / 2.0 / BLENDER_LENS_MM))
R2N2_MAX_DISTANCE = 1.75
AZIMUTH_RANGE = (0.0, 360.0)
ELEVATION_RANGE = (25.0, 30.0)
DISTANCE_RATIO_RANGE = (0.65, 0.95)
WORLD_UP = np.array([0.0, 1.0, 0.0])
# p_frame = M @ p_v1 for a point (or camera offset) given in ShapeNetCore v1's axes.
FRAME_FROM_V1 = {
    "v1": np.eye(3),
    "v2": np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]),
}

ImageSize = Union[int, Sequence[int]]


def image_hw(image_size: ImageSize) -> tuple[int, int]:
    """(H, W) from an int (square) or an (H, W) pair."""
    if isinstance(image_size, (int, np.integer)):
        h = w = int(image_size)
    else:
        h, w = (int(s) for s in image_size)
    if h < 1 or w < 1:
        raise ValueError(f"image size must be positive, got {image_size}")
    return h, w


def intrinsics(fov_deg: float, image_size: ImageSize) -> np.ndarray:
    """Pinhole K [3,3] in pixels for a field of view spanning the larger image side."""
    if not 0.0 < fov_deg < 180.0:
        raise ValueError(f"field of view must be in (0, 180) degrees, got {fov_deg}")
    h, w = image_hw(image_size)
    f = 0.5 * max(h, w) / math.tan(math.radians(fov_deg) / 2.0)
    return np.array([[f, 0.0, w / 2.0], [0.0, f, h / 2.0], [0.0, 0.0, 1.0]])


def orbit_position(azimuth_deg: float, elevation_deg: float, distance: float, frame: str = "v1") -> np.ndarray:
    """Camera centre [3] of an R2N2 view on a sphere of radius `distance` about the origin, in `frame`'s axes."""
    if frame not in FRAME_FROM_V1:
        raise ValueError(f"frame must be one of {sorted(FRAME_FROM_V1)} (ShapeNetCore's axes), got {frame!r}")
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    v1 = distance * np.array([math.cos(el) * math.cos(az), math.sin(el), math.cos(el) * math.sin(az)])
    return FRAME_FROM_V1[frame] @ v1


def look_at_extrinsics(eye: np.ndarray, target: np.ndarray, inplane_deg: float = 0.0) -> np.ndarray:
    """world_to_cam [4,4] (OpenCV axes) of a camera at `eye` looking at `target`, y up."""
    forward = np.asarray(target, float) - np.asarray(eye, float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, WORLD_UP)
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("camera looks straight along the up axis; its roll is undefined")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    # In-plane rotation turns the image axes about the optical axis.
    c, s = math.cos(math.radians(inplane_deg)), math.sin(math.radians(inplane_deg))
    right, down = c * right + s * down, -s * right + c * down
    rotation = np.stack([right, down, forward])
    world_to_cam = np.eye(4)
    world_to_cam[:3, :3] = rotation
    world_to_cam[:3, 3] = -rotation @ np.asarray(eye, float)
    return world_to_cam


def look_at(
    azimuth_deg: float,
    elevation_deg: float,
    distance: float,
    fov_deg: float,
    image_size: ImageSize,
    *,
    inplane_deg: float = 0.0,
    target: Sequence[float] = (0.0, 0.0, 0.0),
    frame: str = "v1",
) -> tuple[np.ndarray, np.ndarray]:
    """(K [3,3], world_to_cam [4,4]) of an orbiting camera looking at `target` (azimuth as R2N2's, in `frame`)."""
    if distance <= 0:
        raise ValueError(f"camera distance must be positive, got {distance}")
    target = np.asarray(target, float)
    eye = target + orbit_position(azimuth_deg, elevation_deg, distance, frame)
    return intrinsics(fov_deg, image_size), look_at_extrinsics(eye, target, inplane_deg)


def sample_r2n2_views(n_views: int, rng: np.random.Generator) -> np.ndarray:
    """R2N2 metadata rows [V,5]: (azimuth, elevation, inplane=0, distance_ratio, fov) per view."""
    if n_views < 1:
        raise ValueError(f"n_views must be at least 1, got {n_views}")
    rows = np.zeros((n_views, 5))
    rows[:, 0] = rng.uniform(*AZIMUTH_RANGE, size=n_views)
    rows[:, 1] = rng.uniform(*ELEVATION_RANGE, size=n_views)
    rows[:, 3] = rng.uniform(*DISTANCE_RATIO_RANGE, size=n_views)
    rows[:, 4] = R2N2_FOV_DEG
    return rows


def metadata_to_cameras(
    rows: np.ndarray,
    image_size: ImageSize,
    *,
    r2n2_centre: Sequence[float] = (0.0, 0.0, 0.0),
    r2n2_scale: float = 1.0,
    fov_deg: float | None = R2N2_FOV_DEG,
    max_distance: float = R2N2_MAX_DISTANCE,
    frame: str = "v1",
) -> tuple[np.ndarray, np.ndarray]:
    """(K [V,3,3], world_to_cam [V,4,4]) in our frame from R2N2 metadata rows [V,5].

    fov_deg=None takes each row's fifth column as the field of view. `frame` names the axes of the
    mesh the cameras look at: "v1" (R2N2's own, and ushape's shapes) or "v2" (ShapeNetCore.v2).
    """
    rows = np.atleast_2d(np.asarray(rows, dtype=np.float64))
    if rows.shape[1] != 5:
        raise ValueError(f"metadata rows must have 5 columns (az el inplane dist_ratio fov), got {rows.shape}")
    if r2n2_scale <= 0:
        raise ValueError(f"r2n2_scale must be positive, got {r2n2_scale}")
    Ks, extrinsics = [], []
    for az, el, inplane, ratio, row_fov in rows:
        K, w2c = look_at(
            az,
            el,
            ratio * max_distance / r2n2_scale,
            row_fov if fov_deg is None else fov_deg,
            image_size,
            inplane_deg=inplane,
            target=r2n2_centre,
            frame=frame,
        )
        Ks.append(K)
        extrinsics.append(w2c)
    return np.stack(Ks), np.stack(extrinsics)


def format_metadata(rows: np.ndarray) -> str:
    """rendering_metadata.txt text: one "az el inplane dist_ratio fov" line per view."""
    return "".join(" ".join(f"{v:.10g}" for v in row) + "\n" for row in np.atleast_2d(rows))


def parse_metadata(text: str) -> np.ndarray:
    """Metadata rows [V,5] from rendering_metadata.txt text."""
    rows = [line.split() for line in text.splitlines() if line.strip()]
    if not rows or any(len(r) != 5 for r in rows):
        raise ValueError("rendering metadata must have one 'az el inplane dist_ratio fov' line per view")
    return np.array(rows, dtype=np.float64)


def camera_centre(world_to_cam: np.ndarray) -> np.ndarray:
    """Camera centre in world coordinates [..., 3] from world_to_cam [..., 4, 4]."""
    R, t = world_to_cam[..., :3, :3], world_to_cam[..., :3, 3]
    return -np.einsum("...ji,...j->...i", R, t)


def project(points: np.ndarray, K: np.ndarray, world_to_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates [N,2] (u right, v down) and camera depth [N] of world points [N,3]."""
    cam = points @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
    uvw = cam @ K.T
    return uvw[:, :2] / uvw[:, 2:3], cam[:, 2]
