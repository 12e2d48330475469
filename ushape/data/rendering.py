"""CPU ray casting of triangle meshes into RGBA images, masks and depth maps.

One ray per pixel centre (conventions in `ushape.data.cameras`), first hits found with
Embree through trimesh. Depth is the camera-frame z of the hit (OpenCV, same units as the
mesh), 0 where the ray misses; the RGBA background is fully transparent (alpha 0).
"""

from __future__ import annotations

import warnings
from typing import Optional

import numpy as np
import trimesh
import trimesh.ray

from ushape.data.cameras import ImageSize, camera_centre, image_hw
from ushape.data.shading import ColourFn, Lighting, constant_colour_fn, mesh_colour_fn, shade, surface_normals

_warned_no_embree = False


def pixel_rays(K: np.ndarray, world_to_cam: np.ndarray, image_size: ImageSize) -> tuple[np.ndarray, np.ndarray]:
    """World ray origins [H*W,3] and directions [H*W,3] (row-major pixels, camera-z component 1)."""
    h, w = image_hw(image_size)
    v, u = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    pixels = np.stack([u.ravel(), v.ravel(), np.ones(h * w)], axis=1)
    dirs_cam = pixels @ np.linalg.inv(K).T
    dirs_world = dirs_cam @ world_to_cam[:3, :3]  # R^T d, row-wise
    origins = np.broadcast_to(camera_centre(world_to_cam), dirs_world.shape)
    return np.ascontiguousarray(origins), dirs_world


def ray_intersector(mesh: trimesh.Trimesh):
    """The mesh's ray intersector, Embree when available (trimesh caches it on the mesh)."""
    global _warned_no_embree
    if not trimesh.ray.has_embree and not _warned_no_embree:
        warnings.warn("embreex is not importable: falling back to trimesh's pure-Python ray tests, "
                      "which are ~100x slower (pip install embreex)")
        _warned_no_embree = True
    return mesh.ray


def render_mesh(
    mesh: trimesh.Trimesh,
    K: np.ndarray,
    world_to_cam: np.ndarray,
    image_size: ImageSize,
    colour_fn: Optional[ColourFn] = None,
    *,
    lighting: Lighting = Lighting(),
    smooth_normals: bool = True,
) -> dict[str, np.ndarray]:
    """One view: {"rgba": uint8 [H,W,4], "mask": bool [H,W], "depth": float32 [H,W] (0 = miss)}.

    colour_fn(points [N,3], face_index [N]) -> albedo [N,3] in [0,1]; None uses the mesh's own
    colours if it has any, else a light grey.
    """
    if len(mesh.faces) == 0:
        raise ValueError("cannot render a mesh with no faces")
    K, world_to_cam = np.asarray(K, np.float64), np.asarray(world_to_cam, np.float64)
    if K.shape != (3, 3) or world_to_cam.shape != (4, 4):
        raise ValueError(f"expected K [3,3] and world_to_cam [4,4], got {K.shape} and {world_to_cam.shape}")
    h, w = image_hw(image_size)
    origins, directions = pixel_rays(K, world_to_cam, (h, w))
    face, ray, hits = ray_intersector(mesh).intersects_id(
        origins, directions, multiple_hits=False, return_locations=True
    )

    rgba = np.zeros((h * w, 4), np.uint8)
    depth = np.zeros(h * w, np.float32)
    if len(ray):
        view_dirs = directions[ray] / np.linalg.norm(directions[ray], axis=1, keepdims=True)
        normals = surface_normals(mesh, hits, face, view_dirs, smooth=smooth_normals)
        colour_fn = colour_fn or mesh_colour_fn(mesh) or constant_colour_fn()
        albedo = np.asarray(colour_fn(hits, face), np.float64)
        rgb = shade(albedo, normals, view_dirs, lighting)
        rgba[ray, :3] = np.round(rgb * 255.0).astype(np.uint8)
        rgba[ray, 3] = 255
        depth[ray] = hits @ world_to_cam[2, :3] + world_to_cam[2, 3]
    mask = rgba[:, 3] > 0
    return {"rgba": rgba.reshape(h, w, 4), "mask": mask.reshape(h, w), "depth": depth.reshape(h, w)}


def render_views(
    mesh: trimesh.Trimesh,
    Ks: np.ndarray,
    world_to_cams: np.ndarray,
    image_size: ImageSize,
    colour_fn: Optional[ColourFn] = None,
    **kwargs,
) -> dict[str, np.ndarray]:
    """Many views stacked: rgba [V,H,W,4], mask [V,H,W], depth [V,H,W] (Ks [V,3,3], world_to_cams [V,4,4])."""
    if len(Ks) != len(world_to_cams):
        raise ValueError(f"{len(Ks)} intrinsics but {len(world_to_cams)} extrinsics")
    views = [render_mesh(mesh, K, w2c, image_size, colour_fn, **kwargs) for K, w2c in zip(Ks, world_to_cams)]
    return {key: np.stack([v[key] for v in views]) for key in ("rgba", "mask", "depth")}
