"""CPU ray casting of triangle meshes into RGBA images, masks and depth maps.

One ray per pixel centre (conventions in `ushape.data.cameras`), first hits found with
Embree (embreex). Depth is the camera-frame z of the hit (OpenCV, same units as the
mesh), 0 where the ray misses; the RGBA background is fully transparent (alpha 0).
"""

from __future__ import annotations

from typing import Optional, Union

import numpy as np
import trimesh
import trimesh.ray

from ushape.data.cameras import ImageSize, camera_centre, image_hw
from ushape.data.shading import ColourFn, Lighting, constant_colour_fn, mesh_colour_fn, shade, surface_normals


def pixel_rays(K: np.ndarray, world_to_cam: np.ndarray, image_size: ImageSize) -> tuple[np.ndarray, np.ndarray]:
    """World ray origins [H*W,3] and directions [H*W,3] (row-major pixels, camera-z component 1)."""
    h, w = image_hw(image_size)
    v, u = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    pixels = np.stack([u.ravel(), v.ravel(), np.ones(h * w)], axis=1)
    dirs_cam = pixels @ np.linalg.inv(K).T
    dirs_world = dirs_cam @ world_to_cam[:3, :3]  # R^T d, row-wise
    origins = np.broadcast_to(camera_centre(world_to_cam), dirs_world.shape)
    return np.ascontiguousarray(origins), dirs_world


def face_and_vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit face normals [F,3] and area-weighted unit vertex normals [V,3] of a triangle mesh."""
    tri = vertices[faces]
    scaled = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = twice the face area
    summed = np.stack([np.bincount(faces.ravel(), np.repeat(scaled[:, k], 3), len(vertices)) for k in range(3)], 1)

    def unit(x: np.ndarray) -> np.ndarray:
        return x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-20)

    return unit(scaled), unit(summed)


class RayCaster:
    """First-hit ray queries against one mesh; its acceleration structure and arrays are built
    once, so many views of the same mesh pay for them once."""

    def __init__(self, mesh: trimesh.Trimesh, smooth_normals: bool = True) -> None:
        if len(mesh.faces) == 0:
            raise ValueError("cannot render a mesh with no faces")
        if not trimesh.ray.has_embree:
            raise ImportError(
                "ray casting needs embreex (a ushape dependency, fast BVH ray queries): pip install embreex"
            )
        self.mesh = mesh
        faces = np.asarray(mesh.faces, np.int64)
        vertices = np.asarray(mesh.vertices, np.float64)
        self.triangles = vertices[faces]  # [F,3,3]
        self.face_normals, vertex_normals = face_and_vertex_normals(vertices, faces)
        self.corner_normals = vertex_normals[faces] if smooth_normals else None
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        # Embree is single precision: shift and scale the mesh to a ~100-unit box, like trimesh does.
        self._offset = vertices.min(axis=0)
        self._scale = 100.0 / max(float(np.ptp(vertices, axis=0).max()), 1e-12)
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(
            scene=self._scene,
            vertices=((vertices - self._offset) * self._scale).astype(np.float32),
            indices=faces.astype(np.int32),
        )

    def first_hits(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ray index [M], face index [M], barycentric weights [M,3]) of the rays that hit."""
        out = self._scene.run(
            ((origins - self._offset) * self._scale).astype(np.float32), directions.astype(np.float32), output=1
        )
        ray = np.flatnonzero(out["primID"] >= 0)
        u, v = out["u"][ray].astype(np.float64), out["v"][ray].astype(np.float64)
        return ray, out["primID"][ray].astype(np.int64), np.stack([1.0 - u - v, u, v], axis=1)


def render_mesh(
    mesh: Union[trimesh.Trimesh, RayCaster],
    K: np.ndarray,
    world_to_cam: np.ndarray,
    image_size: ImageSize,
    colour_fn: Optional[ColourFn] = None,
    *,
    lighting: Lighting = Lighting(),
) -> dict[str, np.ndarray]:
    """One view: {"rgba": uint8 [H,W,4], "mask": bool [H,W], "depth": float32 [H,W] (0 = miss)}.

    colour_fn(points [N,3], face_index [N]) -> albedo [N,3] in [0,1]; None uses the mesh's own
    colours if it has any, else a light grey. Pass a RayCaster instead of the mesh to reuse its
    acceleration structure across views.
    """
    caster = mesh if isinstance(mesh, RayCaster) else RayCaster(mesh)
    K, world_to_cam = np.asarray(K, np.float64), np.asarray(world_to_cam, np.float64)
    if K.shape != (3, 3) or world_to_cam.shape != (4, 4):
        raise ValueError(f"expected K [3,3] and world_to_cam [4,4], got {K.shape} and {world_to_cam.shape}")
    h, w = image_hw(image_size)
    origins, directions = pixel_rays(K, world_to_cam, (h, w))
    ray, face, bary = caster.first_hits(origins, directions)

    rgba = np.zeros((h * w, 4), np.uint8)
    depth = np.zeros(h * w, np.float32)
    if len(ray):
        # Hit points from barycentric weights are exact on the triangle, free of Embree's float32 t.
        hits = np.einsum("nk,nkd->nd", bary, caster.triangles[face])
        view_dirs = directions[ray] / np.linalg.norm(directions[ray], axis=1, keepdims=True)
        corners = None if caster.corner_normals is None else caster.corner_normals[face]
        normals = surface_normals(caster.face_normals[face], corners, bary, view_dirs)
        colour_fn = colour_fn or mesh_colour_fn(caster.mesh) or constant_colour_fn()
        albedo = np.asarray(colour_fn(hits, face), np.float64)
        rgb = shade(albedo, normals, view_dirs, lighting)
        rgba[ray, :3] = np.round(rgb * 255.0).astype(np.uint8)
        rgba[ray, 3] = 255
        depth[ray] = hits @ world_to_cam[2, :3] + world_to_cam[2, 3]
    mask = rgba[:, 3] > 0
    return {"rgba": rgba.reshape(h, w, 4), "mask": mask.reshape(h, w), "depth": depth.reshape(h, w)}


def render_views(
    mesh: Union[trimesh.Trimesh, RayCaster],
    Ks: np.ndarray,
    world_to_cams: np.ndarray,
    image_size: ImageSize,
    colour_fn: Optional[ColourFn] = None,
    **kwargs,
) -> dict[str, np.ndarray]:
    """Many views stacked: rgba [V,H,W,4], mask [V,H,W], depth [V,H,W] (Ks [V,3,3], world_to_cams [V,4,4])."""
    if len(Ks) != len(world_to_cams):
        raise ValueError(f"{len(Ks)} intrinsics but {len(world_to_cams)} extrinsics")
    caster = mesh if isinstance(mesh, RayCaster) else RayCaster(mesh)
    views = [render_mesh(caster, K, w2c, image_size, colour_fn, **kwargs) for K, w2c in zip(Ks, world_to_cams)]
    return {key: np.stack([v[key] for v in views]) for key in ("rgba", "mask", "depth")}


def on_white(rgba: np.ndarray) -> np.ndarray:
    """RGB uint8 [H,W,3] of an RGBA image [H,W,4] composited over white."""
    alpha = rgba[..., 3:].astype(np.float64) / 255.0
    return np.round(rgba[..., :3] * alpha + 255.0 * (1.0 - alpha)).astype(np.uint8)
