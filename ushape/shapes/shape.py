"""A generated object: named, coloured parts made of primitives, seen in DeepSDF's normalised frame."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
import trimesh

from ushape.shapes.frame import MIN_THICKNESS, thicken_to_normalised, union_aabb
from ushape.shapes.meshing import mesh_from_sdf
from ushape.shapes.primitives import Primitive


@dataclass(frozen=True, eq=False)
class Part:
    """A named group of primitives (raw frame) drawn in one RGB colour in [0, 1]."""

    name: str
    colour: tuple[float, float, float]
    primitives: tuple[Primitive, ...]


def union_sdf(primitives: Sequence[Primitive], boxes: np.ndarray, points: np.ndarray) -> np.ndarray:
    """[N,3] -> [N] exact min over primitives of their SDF (same frame), evaluating few of them.

    Points are grouped into up to 8^3 bins over their bounding box (about a thousand points per
    bin, so numpy calls stay large). A primitive lies inside its box
    `boxes[i]` ([2,3] lo, hi), so the gap between that box and a bin's box bounds its SDF from
    below for every point of the bin; primitives are tried nearest first, and once that bound
    reaches the bin's worst current value no later primitive can lower any point of the bin.
    """
    n = len(points)
    out = np.empty(n)
    if n == 0:
        return out
    lo, hi = points.min(0), points.max(0)
    cells = int(np.clip(np.cbrt(n / 1000.0), 1, 8))
    bins = np.minimum(((points - lo) / np.maximum(hi - lo, 1e-12) * cells).astype(np.int64), cells - 1)
    key = (bins[:, 0] * cells + bins[:, 1]) * cells + bins[:, 2]
    order = np.argsort(key, kind="stable")
    starts = np.flatnonzero(np.diff(key[order], prepend=-1))
    for start, stop in zip(starts, np.append(starts[1:], n)):
        idx = order[start:stop]
        pts = points[idx]
        p_lo, p_hi = pts.min(0), pts.max(0)
        gap = np.maximum(boxes[:, 0] - p_hi, 0.0) + np.maximum(p_lo - boxes[:, 1], 0.0)
        reach = np.sqrt(np.einsum("ij,ij->i", gap, gap))
        best = np.full(len(idx), np.inf)
        for k in np.argsort(reach):
            if reach[k] >= best.max():
                break
            np.minimum(best, primitives[k].sdf(pts), out=best)
        out[idx] = best
    return out


def _as_points(points: np.ndarray) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape [N, 3], got {p.shape}")
    return p


@dataclass(eq=False)
class Shape:
    """One chair or table. Every method takes and returns the normalised frame.

    `centre` and `scale` map it back to the raw frame (metres, y up, front +Z):
    raw = centre + scale * normalised, and raw distances are scale times normalised ones.
    """

    shape_id: str
    category: str
    style: dict
    part_names: list[str]
    parts: tuple[Part, ...]
    centre: np.ndarray  # [3] raw
    scale: float
    _meshes: dict = field(default_factory=dict, init=False, repr=False)
    _boxes: dict = field(default_factory=dict, init=False, repr=False)

    def _part_boxes(self, part: Part) -> np.ndarray:
        """[K,2,3] bounding boxes of a part's primitives (raw), computed once."""
        if part.name not in self._boxes:
            self._boxes[part.name] = np.array([np.stack(p.aabb()) for p in part.primitives])
        return self._boxes[part.name]

    def part_sdf(self, points: np.ndarray) -> np.ndarray:
        """[N,3] normalised -> [P,N] signed distance to each part (union of its primitives)."""
        raw = self.centre + self.scale * _as_points(points)
        out = np.empty((len(self.parts), len(raw)))
        for i, part in enumerate(self.parts):
            out[i] = union_sdf(part.primitives, self._part_boxes(part), raw)
        return out / self.scale

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """[N,3] normalised -> [N] signed distance to the shape, negative inside (exact outside)."""
        raw = self.centre + self.scale * _as_points(points)
        prims = [prim for part in self.parts for prim in part.primitives]
        boxes = np.concatenate([self._part_boxes(part) for part in self.parts])
        return union_sdf(prims, boxes, raw) / self.scale

    def part_index(self, points: np.ndarray) -> np.ndarray:
        """[N,3] normalised -> [N] index into part_names of the part nearest each point."""
        return np.argmin(self.part_sdf(points), axis=0)

    def part_colours(self) -> np.ndarray:
        """[P,3] RGB in [0, 1], one row per entry of part_names."""
        return np.array([part.colour for part in self.parts], dtype=np.float64)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box (lo [3], hi [3]) of the surface, normalised frame."""
        lo, hi = union_aabb([p for part in self.parts for p in part.primitives])
        return (lo - self.centre) / self.scale, (hi - self.centre) / self.scale

    def mesh(self, resolution: int = 256) -> trimesh.Trimesh:
        """Watertight marching-cubes mesh, normalised frame; `resolution` samples along the longest side.

        Computed once per resolution; each call returns a copy, so callers may transform it.
        """
        if resolution not in self._meshes:
            lo, hi = self.bounds()
            self._meshes[resolution] = mesh_from_sdf(self.sdf, lo, hi, resolution)
        return self._meshes[resolution].copy()


def assemble_shape(
    category: str,
    seed: int,
    style: dict,
    parts: Mapping[str, Sequence[Primitive]],
    colours: Mapping[str, Sequence[float]],
    min_thickness: float = MIN_THICKNESS,
) -> Shape:
    """Build a Shape from raw-frame parts: thicken thin members, then fix DeepSDF's normalisation."""
    names = [name for name, prims in parts.items() if prims]
    missing = [name for name in names if name not in colours]
    if missing:
        raise ValueError(f"assemble_shape: no colour given for parts {missing}")
    flat = [p for name in names for p in parts[name]]
    thick, centre, scale = thicken_to_normalised(flat, min_thickness)
    built, start = [], 0
    for name in names:
        count = len(parts[name])
        colour = tuple(float(np.clip(c, 0.0, 1.0)) for c in colours[name])
        built.append(Part(name=name, colour=colour, primitives=tuple(thick[start : start + count])))
        start += count
    return Shape(
        shape_id=f"{category}_{seed:06d}",
        category=category,
        style=style,
        part_names=names,
        parts=tuple(built),
        centre=centre,
        scale=float(scale),
    )
