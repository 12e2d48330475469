"""Surface colour and lighting for the ray-cast renders (world frame, colours in [0, 1]).

A colour function `colour_fn(points [N,3], face_index [N]) -> albedo [N,3]` decides what a
surface point looks like; `shade` lights it with a headlight, a fixed key light and ambient
light, so renders carry shading cues like ShapeNetRendering's rather than flat silhouettes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
import trimesh

ColourFn = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (points [N,3], face_index [N]) -> [N,3]

DEFAULT_ALBEDO = (0.72, 0.72, 0.72)


@dataclass(frozen=True)
class Lighting:
    """Lambertian headlight (along the view ray) and key light (fixed in the world), ambient, and a
    white headlight highlight so that dark materials still show their form."""

    ambient: float = 0.28
    headlight: float = 0.42
    key: float = 0.45
    key_direction: tuple[float, float, float] = (0.35, 1.0, 0.55)  # world, pointing towards the light
    specular: float = 0.12
    shininess: float = 10.0


def shade(albedo: np.ndarray, normals: np.ndarray, view_dirs: np.ndarray, lighting: Lighting) -> np.ndarray:
    """Lit colour [N,3] of points with albedo [N,3], unit normals [N,3], unit view rays [N,3]."""
    key = np.asarray(lighting.key_direction, float)
    key = key / np.linalg.norm(key)
    head = np.clip(-(normals * view_dirs).sum(1), 0.0, 1.0)
    keyed = np.clip(normals @ key, 0.0, 1.0)
    intensity = lighting.ambient + lighting.headlight * head + lighting.key * keyed
    # For a headlight the Blinn-Phong half vector is the reversed view ray.
    highlight = lighting.specular * head**lighting.shininess
    return np.clip(albedo * intensity[:, None] + highlight[:, None], 0.0, 1.0)


def surface_normals(
    face_normals: np.ndarray, corner_normals: Optional[np.ndarray], bary: np.ndarray, view_dirs: np.ndarray
) -> np.ndarray:
    """Unit normals [N,3] at hit points, turned to face the camera (real meshes are not all oriented).

    face_normals [N,3] of the hit faces; corner_normals [N,3,3] (vertex normals of the hit
    faces' corners) interpolated with barycentric weights bary [N,3] for smooth shading, or
    None for flat shading; view_dirs [N,3] unit rays from the camera.
    """
    if corner_normals is None:
        normals = face_normals.copy()
    else:
        normals = np.einsum("nk,nkd->nd", bary, corner_normals)
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    facing_away = (normals * view_dirs).sum(1) > 0
    normals[facing_away] *= -1.0
    return normals


def wood_grain(points: np.ndarray, part_index: np.ndarray, strength: float) -> np.ndarray:
    """Brightness factor [N] in [1 - strength, 1]: wavy stripes along a per-part axis."""
    if strength <= 0:
        return np.ones(len(points))
    # A golden-angle spiral gives each part its own, well-separated grain direction.
    angle = part_index * 2.39996
    axis = np.stack([np.cos(angle) * 0.6, np.full_like(angle, 0.8), np.sin(angle) * 0.6], axis=1)
    across = np.stack([-np.sin(angle), np.zeros_like(angle), np.cos(angle)], axis=1)
    along = (points * axis).sum(1)
    wobble = 0.35 * np.sin(9.0 * (points * across).sum(1) + 1.7 * part_index)
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * 11.0 * along + 2.0 * wobble)
    fine = 0.5 + 0.5 * np.sin(2 * np.pi * 37.0 * along + 5.0 * wobble)
    return 1.0 - strength * (0.75 * rings**3 + 0.25 * fine)


def part_colour_fn(shape: object, grain_strength: float = 0.12) -> ColourFn:
    """Colour function of a procedural shape: its part colours, modulated by wood grain."""
    colours = np.asarray(shape.part_colours(), dtype=np.float64)

    def colour(points: np.ndarray, face_index: np.ndarray) -> np.ndarray:
        part = np.asarray(shape.part_index(points)).astype(np.int64)
        if part.size and (part.min() < 0 or part.max() >= len(colours)):
            raise ValueError(
                f"part_index returned {part.min()}..{part.max()} but there are {len(colours)} part colours"
            )
        return colours[part] * wood_grain(points, part, grain_strength)[:, None]

    return colour


def mesh_colour_fn(mesh: trimesh.Trimesh) -> Optional[ColourFn]:
    """Colour function from the mesh's own face/vertex colours or texture; None if it has none."""
    visual = mesh.visual
    if isinstance(visual, trimesh.visual.texture.TextureVisuals):
        if visual.material is None or getattr(visual, "uv", None) is None:
            return None
        visual = visual.to_color()
    kind = getattr(visual, "kind", None)
    if kind == "face":
        face_rgb = np.asarray(visual.face_colors[:, :3], np.float64) / 255.0
        return lambda points, face_index: face_rgb[face_index]
    if kind == "vertex":
        vertex_rgb = np.asarray(visual.vertex_colors[:, :3], np.float64) / 255.0

        def colour(points: np.ndarray, face_index: np.ndarray) -> np.ndarray:
            bary = trimesh.triangles.points_to_barycentric(mesh.triangles[face_index], points)
            return np.einsum("nk,nkd->nd", bary, vertex_rgb[mesh.faces[face_index]])

        return colour
    return None


def constant_colour_fn(rgb: tuple[float, float, float] = DEFAULT_ALBEDO) -> ColourFn:
    """Colour function painting every point `rgb`."""
    albedo = np.asarray(rgb, np.float64)
    return lambda points, face_index: np.broadcast_to(albedo, (len(points), 3))
