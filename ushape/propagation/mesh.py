"""SDF uncertainty at points and mesh vertices, and the grid over [-1, 1]^3 those points are laid on (see field.py)."""

from __future__ import annotations

import importlib
import inspect
from typing import Callable

import torch
from omegaconf import OmegaConf
from torch import Tensor

from ushape.builders import yaml_files
from ushape.decoder.query import Decoder
from ushape.mesh.extraction import grid_points as mesh_grid_points
from ushape.propagation.monte_carlo import propagate_mc
from ushape.workspace import CONFIG_DIR

# How a latent Gaussian reaches the SDF: one YAML file a method, conf/propagation/<name>.yaml, whose `_target_`
# is a function (decoder, mu [D], var [D] or [D, D], points [P, 3], ...) -> (mean [P], variance [P]) taking
# any of n_samples, generator, chunk and bf16 that it uses.
PROPAGATION_DIR = CONFIG_DIR / "propagation"
METHODS = tuple(yaml_files(PROPAGATION_DIR))


def propagator(method: str) -> Callable[..., tuple[Tensor, Tensor]]:
    """The propagation function conf/propagation/<method>.yaml names."""
    path = PROPAGATION_DIR / f"{method}.yaml"
    if method not in METHODS:
        raise ValueError(f"unknown propagation method {method!r}; choose one of {METHODS}")
    module, _, name = str(OmegaConf.load(path)["_target_"]).rpartition(".")
    return getattr(importlib.import_module(module), name)


def grid_points(resolution: int, dtype: torch.dtype = torch.float32, device: str | torch.device = "cpu") -> Tensor:
    """Points [N^3, 3] of the N^3 grid over [-1, 1]^3, coordinate -1 + i * 2/(N-1), x slowest (ij order)."""
    if isinstance(resolution, bool) or not isinstance(resolution, int) or resolution < 2:
        raise ValueError(f"resolution must be an integer >= 2 (grid points per axis), got {resolution!r}")
    # The mesh extractor's grid, so an uncertainty grid lines up with the SDF grid it colours.
    return mesh_grid_points(resolution).to(dtype=dtype, device=device)


def propagate(
    decoder: Decoder,
    mu: Tensor,  # [D]
    var: Tensor,  # [D] or [D, D] (a full covariance)
    points: Tensor,  # [P, 3]
    method: str = "mc",
    n_samples: int = 10,
    generator: torch.Generator | None = None,
    chunk: int | None = None,
    bf16: bool = False,
) -> tuple[Tensor, Tensor]:
    """SDF mean [P] and variance [P] at points by a method of conf/propagation/: Monte Carlo ("mc"),
    first order ("linearised"), ...; each is given the options it takes."""
    function = propagator(method)
    options = {"n_samples": n_samples, "generator": generator, "bf16": bf16}
    if chunk is not None:
        options["chunk"] = chunk
    taken = inspect.signature(function).parameters
    return function(decoder, mu, var, points, **{k: v for k, v in options.items() if k in taken})


def vertex_uncertainty(
    decoder: Decoder,
    mu: Tensor,  # [D]
    var: Tensor,  # [D] or [D, D] (a full covariance)
    vertices: Tensor,  # [V, 3]
    method: str = "mc",
    n_samples: int = 10,
    generator: torch.Generator | None = None,
    chunk: int | None = None,
    bf16: bool = False,
) -> Tensor:  # [V]
    """Standard deviation of the SDF at each mesh vertex (the paper's per-vertex mesh colouring)."""
    _, variance = propagate(decoder, mu, var, vertices, method, n_samples, generator, chunk, bf16)
    return variance.sqrt()


# DeepSDF's training clamp distance: SDF values beyond it carry no training signal, so they are scored clamped.
SDF_CLAMP = 0.1


def propagate_to_sdf(
    decoder,
    mu: Tensor,
    var: Tensor,
    points: Tensor,
    method: str = "mc",
    n_samples: int = 10,
    seed: int = 0,
    clamp: float | None = SDF_CLAMP,
    bf16: bool = False,
) -> tuple[Tensor, Tensor]:
    """SDF mean and variance [P] at points [P, 3] for one latent Gaussian (mu [D], var [D] or [D, D]), clamped values.

    Monte Carlo clamps every sample before its statistics; the linearised method clamps the mean
    and zeroes the variance where the mean is beyond the clamp (the clamp's derivative there is 0).
    """
    generator = torch.Generator().manual_seed(seed)
    if method == "mc" and clamp is not None:
        _, _, samples = propagate_mc(decoder, mu, var, points, n_samples, generator, bf16=bf16, return_samples=True)
        samples = samples.clamp(-clamp, clamp)
        return samples.mean(dim=0), samples.var(dim=0, correction=1)
    mean, variance = propagate(decoder, mu, var, points, method, n_samples, generator, bf16=bf16)
    if clamp is not None:
        variance = torch.where(mean.abs() < clamp, variance, torch.zeros_like(variance))
        mean = mean.clamp(-clamp, clamp)
    return mean, variance


def clamped_sdf_predictions(
    decoder,
    mu: Tensor,  # [R, D]
    var: Tensor,  # [R, D] or [R, D, D]
    points: Tensor,  # [P, 3]
    sdf_true: Tensor,  # [P]
) -> tuple[Tensor, Tensor, Tensor]:
    """(|error| [R, P], variance [R, P], mean [R, P]) of the linearised SDF of each Gaussian at a shape's
    ground-truth samples, all clamped as evaluation clamps them, before any SDF calibration."""
    errors, variances, means = [], [], []
    truth = sdf_true.clamp(-SDF_CLAMP, SDF_CLAMP)
    for code_mu, code_var in zip(mu, var):
        mean, variance = propagate_to_sdf(decoder, code_mu, code_var, points, "linearised", clamp=SDF_CLAMP)
        errors.append((mean - truth).abs()), variances.append(variance), means.append(mean)
    return torch.stack(errors), torch.stack(variances), torch.stack(means)


def clamped_sdf_errors(
    decoder,
    mu: Tensor,  # [R, D]
    var: Tensor,  # [R, D] or [R, D, D]
    points: Tensor,  # [P, 3]
    sdf_true: Tensor,  # [P]
    temperature: float | None = None,
    floor: float | None = None,
    distance_scale: float | None = None,
) -> tuple[Tensor, Tensor]:
    """(|error| [R, P], std [R, P]) of the linearised SDF of each Gaussian at a shape's ground-truth samples, both
    clamped as evaluation clamps them, with the SDF calibration where given: T var + floor^2 + (b |mean|)^2 (T the
    SDF-space temperature, the floor a std, b the distance scale on the clamped mean's distance from the surface;
    `ushape.recalibration.sdf_distance`)."""
    errors, variance, mean = clamped_sdf_predictions(decoder, mu, var, points, sdf_true)
    if temperature is not None:
        variance = variance * temperature
    if floor is not None:
        variance = variance + floor**2
    if distance_scale is not None:
        variance = variance + (distance_scale * mean).square()
    return errors, variance.sqrt()
