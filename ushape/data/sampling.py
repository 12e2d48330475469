"""SDF training samples prepared the way DeepSDF prepares them, in the shape's normalised frame.

DeepSDF (PreprocessMesh.cpp) takes 47 of every 50 points near the surface: surface points
jittered with zero-mean Gaussian noise, half with variance 0.005 and half with variance
0.0005, so the decoder sees both the coarse band and the thin shell around the zero level
set; the other 3 of 50 are uniform in the bounding cube [-1, 1]^3 so far-field signs are
learnt too. Samples are stored split by sign, like DeepSDF's npz files ("pos", "neg").

Generic over any `sdf_fn(points [N,3]) -> [N]` and any trimesh mesh, so real datasets with a
mesh-based SDF can reuse it.
"""

from __future__ import annotations

from typing import Callable, Union

import numpy as np
import trimesh

SdfFn = Callable[[np.ndarray], np.ndarray]  # points [N,3] -> sdf [N]

NEAR_SURFACE_FRACTION = 47 / 50
NEAR_SURFACE_VARIANCES = (0.005, 0.0005)
UNIFORM_BOUND = 1.0


def sample_counts(n_points: int) -> tuple[int, int, int]:
    """How many points go to (coarse-noise band, fine-noise band, uniform cube) out of n_points."""
    if n_points < 2:
        raise ValueError(f"n_points must be at least 2 to split near-surface/uniform samples, got {n_points}")
    n_near = int(round(n_points * NEAR_SURFACE_FRACTION))
    n_coarse = n_near // 2
    return n_coarse, n_near - n_coarse, n_points - n_near


def sample_points(mesh: trimesh.Trimesh, n_points: int, rng: np.random.Generator) -> np.ndarray:
    """DeepSDF query points [n_points, 3]: perturbed surface points first, uniform cube points last."""
    if len(mesh.faces) == 0:
        raise ValueError("cannot sample SDF points near an empty mesh (0 faces)")
    n_coarse, n_fine, n_uniform = sample_counts(n_points)
    surface, _ = area_weighted_surface_points(mesh, n_coarse + n_fine, rng)
    std = np.repeat(np.sqrt(NEAR_SURFACE_VARIANCES), [n_coarse, n_fine])[:, None]
    near = surface + rng.normal(size=surface.shape) * std
    uniform = rng.uniform(-UNIFORM_BOUND, UNIFORM_BOUND, size=(n_uniform, 3))
    return np.concatenate([near, uniform], axis=0)


def split_by_sign(points: np.ndarray, sdf: np.ndarray) -> dict[str, np.ndarray]:
    """DeepSDF npz layout: pos [P,4] (sdf >= 0) and neg [Q,4] (sdf < 0), rows xyz+sdf, float32."""
    if points.shape[0] != sdf.shape[0]:
        raise ValueError(f"{points.shape[0]} points but {sdf.shape[0]} SDF values")
    rows = np.concatenate([points, sdf[:, None]], axis=1).astype(np.float32)
    outside = rows[:, 3] >= 0
    return {"pos": rows[outside], "neg": rows[~outside]}


def sample_sdf(
    shape_or_sdf_fn: Union[SdfFn, object],
    mesh: trimesh.Trimesh,
    n_points: int,
    rng: np.random.Generator,
) -> dict[str, np.ndarray]:
    """DeepSDF samples of one shape: {"pos": [P,4], "neg": [Q,4]} float32 with P + Q = n_points.

    `shape_or_sdf_fn` is a callable `points [N,3] -> sdf [N]` or an object with such an
    `.sdf` method; `mesh` supplies the surface the near-surface points are drawn from.
    """
    sdf_fn = _as_sdf_fn(shape_or_sdf_fn)
    points = sample_points(mesh, n_points, rng)
    sdf = np.asarray(sdf_fn(points), dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(sdf)):
        raise ValueError("sdf_fn returned non-finite values; check the shape's SDF")
    return split_by_sign(points, sdf)


def _as_sdf_fn(shape_or_sdf_fn: Union[SdfFn, object]) -> SdfFn:
    sdf = getattr(shape_or_sdf_fn, "sdf", None)
    if callable(sdf):
        return sdf
    if callable(shape_or_sdf_fn):
        return shape_or_sdf_fn
    raise TypeError(
        f"expected a callable sdf_fn(points)->values or an object with an .sdf method, "
        f"got {type(shape_or_sdf_fn).__name__}"
    )


def area_weighted_surface_points(
    mesh: trimesh.Trimesh, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Uniform points on the mesh surface [n,3] and the face each lies on [n] (faces chosen by area)."""
    areas = mesh.area_faces
    face = rng.choice(len(areas), size=n, p=areas / areas.sum())
    # Uniform barycentric coordinates by folding the unit square onto the triangle.
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    tri = mesh.triangles[face]
    return tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0]), face
