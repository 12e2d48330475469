"""Solid primitives with exact signed distance functions, placed by a rigid transform (raw frame).

Every primitive answers four questions the shape needs: its signed distance at points [N,3]
(negative inside), its axis-aligned bounding box, the farthest distance of its surface from a
point (for DeepSDF's unit-sphere scaling) and a copy with no dimension thinner than a given size
(so marching cubes keeps thin legs and slats). Distances are exact everywhere for each primitive;
the rounded variants are exact Minkowski sums of a shrunk solid and a ball.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ushape.shapes.planar import ellipse_sdf, rounded_rect_sdf
from ushape.shapes.rigid import frame_along

_IDENTITY = np.eye(3)


def _row_norm(v: np.ndarray) -> np.ndarray:
    """[N,K] -> [N] Euclidean norm of each row."""
    return np.sqrt(np.einsum("ij,ij->i", v, v))


def _vec(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64).reshape(3)


def _circle_half_extent(normal: np.ndarray, radius: float) -> np.ndarray:
    """[3] half extent along x, y, z of a circle of `radius` whose plane has unit `normal`."""
    return radius * np.sqrt(np.clip(1.0 - normal**2, 0.0, None))


def _circle_max_distance(point: np.ndarray, centre: np.ndarray, normal: np.ndarray, radius: float) -> float:
    """Largest distance from `point` to a circle (centre, unit normal, radius) in 3D."""
    v = point - centre
    along = float(np.dot(v, normal))
    across = float(np.linalg.norm(v - along * normal))
    return float(np.hypot(along, across + radius))


@dataclass(frozen=True, eq=False)
class Primitive:
    """Base: a solid at `centre` with local axes `rotation` ([3,3], columns = local axes)."""

    centre: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotation: np.ndarray = field(default_factory=lambda: _IDENTITY.copy())

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre", _vec(self.centre))
        rotation = np.asarray(self.rotation, dtype=np.float64)
        if rotation.shape != (3, 3) or not np.allclose(rotation.T @ rotation, _IDENTITY, atol=1e-8):
            raise ValueError(f"{type(self).__name__}: rotation must be a 3x3 orthonormal matrix")
        object.__setattr__(self, "rotation", rotation)

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """[N,3] parent-frame points -> [N,3] local coordinates (R^T (p - c))."""
        # einsum, not @: a BLAS call on [N,3] x [3,3] is several times slower and spawns threads.
        return np.einsum("ni,ij->nj", points - self.centre, self.rotation)

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """[N,3] -> [N] signed distance in the parent frame's units, negative inside."""
        return self.local_sdf(self.to_local(np.asarray(points, dtype=np.float64)))

    def local_sdf(self, q: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - abstract
        raise NotImplementedError

    def max_distance(self, point: np.ndarray) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def thickened(self, min_size: float) -> "Primitive":  # pragma: no cover - abstract
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class Box(Primitive):
    """Box of half extents `half` (local x, y, z) whose edges are rounded by `radius`."""

    half: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))
    radius: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "half", _vec(self.half))
        if np.any(self.half <= 0) or not 0.0 <= self.radius <= self.half.min():
            raise ValueError(f"Box needs half > 0 and 0 <= radius <= min(half); got {self.half}, {self.radius}")

    @classmethod
    def between(cls, a, b, width: float, depth: float, hint=None, radius: float = 0.0) -> "Box":
        """Beam from point a to point b with cross-section width (local x) by depth (local z)."""
        a, b = _vec(a), _vec(b)
        half = [width / 2, np.linalg.norm(b - a) / 2, depth / 2]
        return cls(centre=(a + b) / 2, rotation=frame_along(b - a, hint), half=half, radius=radius)

    def local_sdf(self, q: np.ndarray) -> np.ndarray:
        d = np.abs(q) - (self.half - self.radius)
        outside = _row_norm(np.maximum(d, 0.0))
        return outside + np.minimum(d.max(axis=1), 0.0) - self.radius

    def _inner_corners(self) -> np.ndarray:
        signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T
        return self.centre + (signs * (self.half - self.radius)) @ self.rotation.T

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        corners = self._inner_corners()
        return corners.min(0) - self.radius, corners.max(0) + self.radius

    def max_distance(self, point: np.ndarray) -> float:
        return float(np.linalg.norm(self._inner_corners() - point, axis=1).max() + self.radius)

    def thickened(self, min_size: float) -> "Box":
        return replace(self, half=np.maximum(self.half, min_size / 2))


@dataclass(frozen=True, eq=False)
class Slab(Primitive):
    """Prism along local y of half height `half_height` over a rounded rectangle or an ellipse.

    `profile` is "rect" (half_x, half_z, corner_radius) or "ellipse" (semi-axes half_x, half_z);
    `edge_radius` rounds the top and bottom rims. Table tops, seats, shelves, discs.
    """

    half_x: float = 0.5
    half_z: float = 0.5
    half_height: float = 0.05
    profile: str = "rect"
    corner_radius: float = 0.0
    edge_radius: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.profile not in ("rect", "ellipse"):
            raise ValueError(f"Slab profile must be 'rect' or 'ellipse', got {self.profile!r}")
        if min(self.half_x, self.half_z, self.half_height) <= 0:
            raise ValueError("Slab needs positive half_x, half_z and half_height")
        if not 0.0 <= self.edge_radius <= min(self.half_x, self.half_z, self.half_height):
            raise ValueError("Slab edge_radius must lie in [0, min(half_x, half_z, half_height)]")
        if not 0.0 <= self.corner_radius <= min(self.half_x, self.half_z):
            raise ValueError("Slab corner_radius must lie in [0, min(half_x, half_z)]")

    def _profile_sdf(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """2D signed distance to the profile shrunk by edge_radius (local x-z plane)."""
        e = self.edge_radius
        if self.profile == "ellipse":
            return ellipse_sdf(x, z, self.half_x - e, self.half_z - e)
        corner = max(self.corner_radius - e, 0.0)
        return rounded_rect_sdf(x, z, self.half_x - e, self.half_z - e, corner)

    def local_sdf(self, q: np.ndarray) -> np.ndarray:
        e = self.edge_radius
        wx = self._profile_sdf(q[:, 0], q[:, 2])
        wy = np.abs(q[:, 1]) - (self.half_height - e)
        outside = np.hypot(np.maximum(wx, 0.0), np.maximum(wy, 0.0))
        return np.minimum(np.maximum(wx, wy), 0.0) + outside - e

    def _rim_points(self) -> np.ndarray:
        """[M,3] parent-frame points on the top and bottom rims of the shrunk prism."""
        e = self.edge_radius
        hx, hz = self.half_x - e, self.half_z - e
        if self.profile == "ellipse":
            t = np.linspace(0.0, 2.0 * np.pi, 2048, endpoint=False)
            xz = np.stack([hx * np.cos(t), hz * np.sin(t)], axis=1)
        else:
            c = max(self.corner_radius - e, 0.0)
            t = np.linspace(0.0, 0.5 * np.pi, 129)
            arc = c * np.stack([np.cos(t), np.sin(t)], axis=1)
            xz = np.concatenate([s * (arc + [hx - c, hz - c]) for s in ([1, 1], [-1, 1], [-1, -1], [1, -1])])
        y = np.full(len(xz), self.half_height - e)
        local = np.concatenate([np.stack([xz[:, 0], y, xz[:, 1]], 1), np.stack([xz[:, 0], -y, xz[:, 1]], 1)])
        return self.centre + local @ self.rotation.T

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        rim = self._rim_points()
        return rim.min(0) - self.edge_radius, rim.max(0) + self.edge_radius

    def max_distance(self, point: np.ndarray) -> float:
        return float(np.linalg.norm(self._rim_points() - point, axis=1).max() + self.edge_radius)

    def thickened(self, min_size: float) -> "Slab":
        h = min_size / 2
        return replace(
            self, half_x=max(self.half_x, h), half_z=max(self.half_z, h), half_height=max(self.half_height, h)
        )


@dataclass(frozen=True, eq=False)
class CappedCone(Primitive):
    """Solid of revolution from end a (radius_a) to end b (radius_b), flat caps; a cylinder if equal."""

    a: np.ndarray = field(default_factory=lambda: np.zeros(3))
    b: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))
    radius_a: float = 0.1
    radius_b: float = 0.1

    def __post_init__(self) -> None:
        object.__setattr__(self, "a", _vec(self.a))
        object.__setattr__(self, "b", _vec(self.b))
        if np.linalg.norm(self.b - self.a) == 0.0 or min(self.radius_a, self.radius_b) <= 0:
            raise ValueError("CappedCone needs distinct end points and positive radii")
        object.__setattr__(self, "centre", (self.a + self.b) / 2)
        super().__post_init__()

    def sdf(self, points: np.ndarray) -> np.ndarray:
        # Exact capped-cone distance (Inigo Quilez): nearest of the caps and the slanted side.
        p = np.asarray(points, dtype=np.float64)
        ba = self.b - self.a
        baba = float(ba @ ba)
        pa = p - self.a
        paba = np.einsum("ij,j->i", pa, ba) / baba
        x = np.sqrt(np.maximum(np.einsum("ij,ij->i", pa, pa) - paba * paba * baba, 0.0))
        ra, rb = self.radius_a, self.radius_b
        rba = rb - ra
        cax = np.maximum(0.0, x - np.where(paba < 0.5, ra, rb))
        cay = np.abs(paba - 0.5) - 0.5
        f = np.clip((rba * (x - ra) + paba * baba) / (rba * rba + baba), 0.0, 1.0)
        cbx = x - ra - f * rba
        cby = paba - f
        sign = np.where((cbx < 0.0) & (cay < 0.0), -1.0, 1.0)
        return sign * np.sqrt(np.minimum(cax * cax + cay * cay * baba, cbx * cbx + cby * cby * baba))

    def _axis(self) -> np.ndarray:
        return (self.b - self.a) / np.linalg.norm(self.b - self.a)

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        n = self._axis()
        ea, eb = _circle_half_extent(n, self.radius_a), _circle_half_extent(n, self.radius_b)
        return np.minimum(self.a - ea, self.b - eb), np.maximum(self.a + ea, self.b + eb)

    def max_distance(self, point: np.ndarray) -> float:
        n = self._axis()
        return max(
            _circle_max_distance(point, self.a, n, self.radius_a),
            _circle_max_distance(point, self.b, n, self.radius_b),
        )

    def thickened(self, min_size: float) -> "CappedCone":
        a, b = self.a, self.b
        length = np.linalg.norm(b - a)
        if length < min_size:
            grow = (min_size - length) / 2 * self._axis()
            a, b = a - grow, b + grow
        r = min_size / 2
        return CappedCone(a=a, b=b, radius_a=max(self.radius_a, r), radius_b=max(self.radius_b, r))


@dataclass(frozen=True, eq=False)
class Capsule(Primitive):
    """Segment a-b swept by a ball of `radius` (a sphere when a == b): tubes, bent frames, glides."""

    a: np.ndarray = field(default_factory=lambda: np.zeros(3))
    b: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))
    radius: float = 0.05

    def __post_init__(self) -> None:
        object.__setattr__(self, "a", _vec(self.a))
        object.__setattr__(self, "b", _vec(self.b))
        if self.radius <= 0:
            raise ValueError("Capsule needs a positive radius")
        object.__setattr__(self, "centre", (self.a + self.b) / 2)
        super().__post_init__()

    def sdf(self, points: np.ndarray) -> np.ndarray:
        p = np.asarray(points, dtype=np.float64)
        ba = self.b - self.a
        baba = float(ba @ ba)
        pa = p - self.a
        t = np.clip(np.einsum("ij,j->i", pa, ba) / baba, 0.0, 1.0) if baba > 0 else np.zeros(len(p))
        return _row_norm(pa - t[:, None] * ba) - self.radius

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        return np.minimum(self.a, self.b) - self.radius, np.maximum(self.a, self.b) + self.radius

    def max_distance(self, point: np.ndarray) -> float:
        return float(max(np.linalg.norm(self.a - point), np.linalg.norm(self.b - point)) + self.radius)

    def thickened(self, min_size: float) -> "Capsule":
        return Capsule(a=self.a, b=self.b, radius=max(self.radius, min_size / 2))


@dataclass(frozen=True, eq=False)
class Torus(Primitive):
    """Ring in the local x-z plane: circle of radius `major` swept by a ball of radius `minor`."""

    major: float = 0.5
    minor: float = 0.05

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0.0 < self.minor < self.major:
            raise ValueError("Torus needs 0 < minor < major")

    def local_sdf(self, q: np.ndarray) -> np.ndarray:
        return np.hypot(np.hypot(q[:, 0], q[:, 2]) - self.major, q[:, 1]) - self.minor

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        extent = _circle_half_extent(self.rotation[:, 1], self.major) + self.minor
        return self.centre - extent, self.centre + extent

    def max_distance(self, point: np.ndarray) -> float:
        return _circle_max_distance(point, self.centre, self.rotation[:, 1], self.major) + self.minor

    def thickened(self, min_size: float) -> "Torus":
        return replace(self, minor=min(max(self.minor, min_size / 2), 0.9 * self.major))
