"""SDF mean and variance on a grid, computed only in the narrow band around the surface.

The mesh and its uncertainty live where the SDF can cross zero. Coarse-to-fine extraction
(`ushape.mesh.extraction.coarse_to_fine_fields`) already finds those cells: it evaluates a coarse
grid everywhere and refines only blocks whose corners are within reach of the surface. Here each of
its evaluations returns the SDF's mean and variance together, so the variance is computed exactly
at those points (the band, plus the coarse grid) and the far field, mean and variance alike, is
the trilinear interpolation of the coarse corners around it. Inside the band the values are those
of the dense computation (tested); far from the surface the mean keeps its sign, which is what
marching cubes reads, and the variance is a smooth estimate from the coarse grid.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from ushape.mesh.extraction import DEFAULT_CHUNK, coarse_to_fine_fields
from ushape.propagation.decoding import Decoder, check_code_size, check_latent_gaussian
from ushape.propagation.linearised import propagate_linearised
from ushape.propagation.monte_carlo import code_statistics, sample_codes

BAND_METHODS = ("linearised", "mc")


class BandField(NamedTuple):
    """Grids [N, N, N] over [-1, 1]^3 in the layout of `ushape.propagation.mesh.grid_points`."""

    mean: Tensor  # SDF mean
    variance: Tensor  # SDF variance
    band: Tensor  # bool: computed here (elsewhere interpolated from the coarse grid)
    evaluations: int  # grid points computed (N^3 for the dense grid)


def narrow_band_field(
    decoder: Decoder,
    mu: Tensor,  # [D]
    var: Tensor,  # [D]
    resolution: int,
    method: str = "linearised",
    n_samples: int = 10,
    generator: torch.Generator | None = None,
    coarse_resolution: int = 32,
    safety: float = 1.2,
    chunk: int = DEFAULT_CHUNK,
) -> BandField:
    """SDF mean and variance grids at N^3, with the variance computed only where the surface can be.

    "linearised" refines on f(x, mu); "mc" draws its M codes once (so every point sees the same codes,
    as the dense MC field with the same generator does) and refines on their mean.
    """
    check_latent_gaussian(mu, var)
    check_code_size(decoder, mu.shape[0])
    if method == "linearised":
        def field(points: Tensor) -> Tensor:
            return torch.stack(propagate_linearised(decoder, mu, var, points.to(mu.dtype), chunk=chunk), dim=-1)
    elif method == "mc":
        if isinstance(n_samples, bool) or not isinstance(n_samples, int) or n_samples < 2:
            raise ValueError(f"n_samples must be an integer >= 2 for mc (got {n_samples!r})")
        codes = sample_codes(mu, var, n_samples, generator)

        def field(points: Tensor) -> Tensor:
            return torch.stack(code_statistics(decoder, codes, points.to(mu.dtype)), dim=-1)
    else:
        raise ValueError(f"unknown propagation method {method!r}; choose one of {BAND_METHODS}")
    coarse = min(coarse_resolution, resolution)
    fields, known = coarse_to_fine_fields(field, 2, resolution, coarse, safety, chunk)
    return BandField(fields[..., 0], fields[..., 1].clamp_min(0.0), known, int(known.sum()))
