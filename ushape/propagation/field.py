"""SDF mean and variance over the N^3 grid in [-1, 1]^3: dense, or with the variance only in the narrow band.

`field_uncertainty` computes every grid point (region "dense") or only the narrow band around the
surface (region "narrow_band", `narrow_band_field`), in two passes:
1. the mean: coarse-to-fine extraction of f(x, mu) (`ushape.mesh.extraction.coarse_to_fine_grid`)
   evaluates a coarse grid everywhere and refines only blocks within reach of the surface; the rest
   is interpolated from block corners (same sign, which is all marching cubes reads);
2. the variance, linearised or Monte Carlo, in the band: the corners of every cell whose mean
   changes sign (the cells marching cubes turns into faces, so every vertex's variance is
   interpolated from computed values), widened by `band_cells` cells; and on a far grid of
   `far_resolution`^3 points, from which the variance elsewhere is interpolated trilinearly.
Inside the band the variance is that of the dense computation (tested); away from it, it is a
smooth estimate. The mean is f(x, mu) for both methods (Monte Carlo's sample mean differs from it by
O(var)); pass 2 costs one forward and one backward (or M forwards) per band point.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
import trimesh
from torch import Tensor
from torch.nn import functional as F

from ushape.decoder.query import Decoder, check_code_size, check_latent_gaussian, code_sdf_fn, decode_points, frozen
from ushape.mesh.extraction import (
    DEFAULT_CHUNK,
    ExtractionStats,
    coarse_to_fine_grid,
    exact_surface,
    extract_mesh,
    marching_cubes,
    surface_cell_corners,
)
from ushape.propagation.mesh import grid_points, propagate

BAND_METHODS = ("linearised", "mc")


class BandField(NamedTuple):
    """Grids [N, N, N] over [-1, 1]^3 in the layout of `ushape.propagation.mesh.grid_points`."""

    mean: Tensor  # SDF at the mean code: computed near the surface and on the coarse grid, else interpolated
    variance: Tensor  # SDF variance: computed in the band, else interpolated from the far grid
    band: Tensor  # bool: where the variance was computed
    evaluations: int  # decoder evaluations of pass 1 (the mean)
    band_points: int  # points whose variance was computed (band + far grid)


def narrow_band_field(
    decoder: Decoder,
    mu: Tensor,  # [D]
    var: Tensor,  # [D] or [D, D] (a full covariance)
    resolution: int,
    method: str = "linearised",
    n_samples: int = 10,
    generator: torch.Generator | None = None,
    coarse_resolution: int = 17,
    safety: float = 1.2,
    band_cells: int = 0,
    far_resolution: int = 17,
    chunk: int = DEFAULT_CHUNK,
    bf16: bool = False,
) -> BandField:
    """SDF mean and variance grids at N^3, with the variance computed only around the surface's cells.

    "mc" draws its M codes once per call from `generator`, as the dense MC field does, so the two
    agree exactly in the band when given generators in the same state. The coarse grid of pass 1 is
    17^3 (blocks of 8 cells at 128^3): on the chair decoders it gave the same mesh as 32^3 with 7-16%
    fewer evaluations. Under bf16 the mean's surface cells are evaluated again in fp32
    (`ushape.mesh.extraction.exact_surface`), so the band and the mesh are those of fp32.
    """
    check_latent_gaussian(mu, var)
    check_code_size(decoder, mu.shape[0])
    if method not in BAND_METHODS:
        raise ValueError(f"unknown propagation method {method!r}; choose one of {BAND_METHODS}")
    if isinstance(band_cells, bool) or not isinstance(band_cells, int) or band_cells < 0:
        raise ValueError(f"band_cells must be an integer >= 0, got {band_cells!r}")
    if isinstance(far_resolution, bool) or not isinstance(far_resolution, int) or far_resolution < 2:
        raise ValueError(f"far_resolution must be an integer >= 2, got {far_resolution!r}")

    def sdf(points: Tensor, half: bool = bf16) -> Tensor:  # [P, 3] -> [P]
        return decode_points(decoder, mu, points.to(mu.dtype), chunk, half)

    mean, evaluations = coarse_to_fine_grid(sdf, resolution, min(coarse_resolution, resolution), safety, chunk)
    if bf16:
        mean, exact = exact_surface(mean, lambda points: sdf(points, False), chunk)
        evaluations += exact
    band = surface_cell_corners(mean, band_cells)
    points = torch.cat([grid_points(resolution)[band.reshape(-1)], grid_points(far_resolution)])
    mc_chunk = None if method == "mc" else chunk  # MC's own default: M codes meet each chunk
    _, variance = propagate(decoder, mu, var, points.to(mu.dtype), method, n_samples, generator, mc_chunk, bf16)
    variance = variance.float().clamp_min(0.0)
    n_band = int(band.sum())
    far = variance[n_band:].reshape(1, 1, *(far_resolution,) * 3)
    grid = F.interpolate(far, size=(resolution,) * 3, mode="trilinear", align_corners=True)[0, 0]
    grid[band] = variance[:n_band]
    return BandField(mean, grid, band, evaluations, points.shape[0])


def field_uncertainty(
    decoder: Decoder,
    mu: Tensor,  # [D]
    var: Tensor,  # [D] or [D, D] (a full covariance)
    resolution: int,
    method: str = "linearised",
    n_samples: int = 10,
    generator: torch.Generator | None = None,
    chunk: int | None = None,
    bf16: bool = False,
    region: str = "dense",
) -> tuple[Tensor, Tensor]:
    """SDF mean and variance grids [N, N, N] over [-1, 1]^3 (see `grid_points` for the layout).

    region "dense" computes every grid point; "narrow_band" computes them only near the surface and
    interpolates the far field from a coarse grid (`narrow_band_field` above, which
    also returns which points were computed), at a fraction of the cost.
    """
    if region == "narrow_band":
        band = narrow_band_field(
            decoder, mu, var, resolution, method, n_samples, generator, chunk=chunk or DEFAULT_CHUNK, bf16=bf16
        )
        return band.mean, band.variance
    if region != "dense":
        raise ValueError(f"region must be 'dense' or 'narrow_band', got {region!r}")
    points = grid_points(resolution, mu.dtype, mu.device)
    mean, variance = propagate(decoder, mu, var, points, method, n_samples, generator, chunk, bf16)
    shape = (resolution,) * 3
    return mean.reshape(shape), variance.reshape(shape)


def decode_field(
    decoder: Decoder,
    z: Tensor,  # [D]
    resolution: int,
    chunk: int = DEFAULT_CHUNK,
    bf16: bool = False,
) -> Tensor:  # [N, N, N]
    """Plain SDF grid [N, N, N] over [-1, 1]^3 for one code, no uncertainty (the cost baseline)."""
    points = grid_points(resolution, z.dtype, z.device)
    return decode_points(decoder, z, points, chunk, bf16).reshape((resolution,) * 3)


def surface_field(
    decoder: Decoder,
    z: Tensor,  # [D]
    resolution: int,
    chunk: int = DEFAULT_CHUNK,
    bf16: bool = False,
) -> Tensor:  # [N, N, N]
    """The dense SDF grid [N, N, N] to mesh: under bf16, the corners of its surface cells are fp32 values.

    bf16 rounds the query points' coordinates by up to 2e-3 and moves thin parts of a mesh by as
    much; re-evaluating only the cells marching cubes meshes (`exact_surface`) keeps the fp32 mesh.
    """
    grid = decode_field(decoder, z, resolution, chunk, bf16)
    if not bf16:
        return grid
    points_dtype = z.dtype

    def exact(points: Tensor) -> Tensor:  # [P, 3] -> [P]
        return decode_points(decoder, z, points.to(dtype=points_dtype, device=z.device), chunk)

    return exact_surface(grid.float().cpu(), exact, chunk)[0].to(grid)


MESH_METHODS = ("dense", "coarse_to_fine")


def code_mesh(
    decoder: Decoder,
    z: Tensor,  # [D]
    resolution: int,
    method: str = "dense",
    bf16: bool = False,
    chunk: int = DEFAULT_CHUNK,
) -> tuple[trimesh.Trimesh, ExtractionStats]:
    """The mesh of one code's zero level set over [-1, 1]^3 at N^3 grid points, and what it cost: the one way
    every part of ushape turns a code into a mesh.

    dense: every grid point decoded (`surface_field`; what evaluation and planning use: a decoder trained on
    SDFs clamped at 0.1 saturates away from the surface, so pruning would evaluate nearly every point anyway);
    coarse_to_fine: a coarse grid (32^3, or N^3 if smaller) then only the cells near its surface
    (`extract_mesh`; reconstruct.py's 128^3 meshes). Under bf16 the search runs in bf16 and the vertices are
    still placed by fp32 values either way. Raises mesh.extraction.EmptySurfaceError without a surface.
    """
    if method == "dense":
        grid = surface_field(decoder, z, resolution, chunk, bf16)
        return marching_cubes(grid), ExtractionStats(resolution, resolution**3, "dense")
    if method != "coarse_to_fine":
        raise ValueError(f"unknown mesh method {method!r}; choose one of {MESH_METHODS}")
    coarse = min(32, resolution)  # extract_mesh's default coarse grid, capped for small meshes
    with frozen(decoder):
        exact = code_sdf_fn(decoder, z) if bf16 else None
        sdf = code_sdf_fn(decoder, z, bf16)
        return extract_mesh(sdf, resolution, "coarse_to_fine", chunk, coarse_resolution=coarse, surface_fn=exact)
