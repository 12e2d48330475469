"""Wall-clock cost of per-pixel depth uncertainty for the views of reconstruct.py: Monte Carlo against implicit.

Cameras: `views` on the protocol's orbit, evenly spread in azimuth, at the middle of R2N2's elevation range
and reconstruct.py's canonical distance and field of view (view_depth.CANONICAL_CAMERA). Monte Carlo draws
n_codes codes once and sphere-traces each per view (reconstruct.py's `--depth-method mc`); the implicit
method traces the mean code once per view and differentiates the hit depth (its default). The implicit
row's note says how well its std maps agree with the Monte Carlo ones just timed, which carry their own
sampling error: a std estimated from M codes is off by about 1/sqrt(2(M-1)) (24 % at M = 10).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from ushape.bench.timing import Measurement, timed
from ushape.data.cameras import look_at
from ushape.propagation.depth_implicit import (
    depth_uncertainty_implicit,
    depth_uncertainty_implicit_views,
    std_agreement,
)
from ushape.propagation.monte_carlo import sample_codes
from ushape.propagation.sphere_tracing import DepthStats, depth_uncertainty
from ushape.reconstruction.view_depth import CANONICAL_CAMERA


def orbit_cameras(views: int, size: int) -> list[tuple]:
    """(K [3, 3], world_to_cam [4, 4]) of `views` cameras evenly spread in azimuth around the object."""
    if isinstance(views, bool) or not isinstance(views, int) or views < 1:
        raise ValueError(f"views must be a positive integer, got {views!r}")
    c = CANONICAL_CAMERA
    return [
        look_at(c["azimuth_deg"] + 360.0 * v / views, c["elevation_deg"], c["distance"], c["fov_deg"], size)
        for v in range(views)
    ]


def pooled_stats(stats: list[DepthStats]) -> DepthStats:
    """Several views' maps side by side as one [H, V*W] map per statistic."""
    return DepthStats(*(torch.cat(maps, dim=1) for maps in zip(*stats)))


def depth_rows(
    decoder: nn.Module,
    mu: Tensor,  # [D]
    var: Tensor,  # [D]
    views: int = 12,
    size: int = 48,
    n_codes: int = 10,
    steps: int = 50,
    seed: int = 0,
    repeats: int = 1,
    reference_codes: int | None = None,
) -> list[Measurement]:
    """Rows "depth uncertainty mc M=<n_codes> (<views> views)" and "depth uncertainty implicit (<views> views)".

    The implicit row's note gives its agreement with the timed Monte Carlo maps and, with reference_codes,
    also with an untimed Monte Carlo run of that many codes (whose own sampling error is small).
    """
    if n_codes < 2 or (reference_codes is not None and reference_codes < 2):
        raise ValueError(
            f"n_codes and reference_codes must be at least 2 for a Monte Carlo std, "
            f"got {n_codes!r} and {reference_codes!r}"
        )
    cameras = orbit_cameras(views, size)
    hw = (size, size)

    def mc(m: int = n_codes) -> list[DepthStats]:
        codes = sample_codes(mu, var, m, torch.Generator().manual_seed(seed))
        return [depth_uncertainty(decoder, codes, K, w2c, hw, steps) for K, w2c in cameras]

    def implicit() -> list[DepthStats]:  # one trace of every view's rays, as reconstruct.py does
        return depth_uncertainty_implicit_views(decoder, mu, var, cameras, hw, steps)

    # The first calls pay for allocator and kernel set-up: keep that out of both rows.
    K, w2c = look_at(0.0, 0.0, CANONICAL_CAMERA["distance"], CANONICAL_CAMERA["fov_deg"], 4)
    depth_uncertainty(decoder, mu[None].float(), K, w2c, (4, 4), steps)
    depth_uncertainty_implicit(decoder, mu, var, K, w2c, (4, 4), steps)
    mc_s, mc_stats = timed(mc, repeats)
    implicit_s, implicit_stats = timed(implicit, repeats)
    hits = int(sum(int((s.hit_rate > 0).sum()) for s in implicit_stats))
    note = (
        f"{size}px, {hits} pixels hit; {mc_s / implicit_s:.1f}x faster than MC M={n_codes}; std vs "
        + agreement_note(implicit_stats, mc_stats, n_codes)
    )
    if reference_codes is not None:
        note += "; vs " + agreement_note(implicit_stats, mc(reference_codes), reference_codes)
    label = f"({views} views)"
    return [
        Measurement(
            f"depth uncertainty mc M={n_codes} {label}",
            mc_s,
            repeats,
            note=f"{size}px, {steps} steps, one code set for all views",
        ),
        Measurement(f"depth uncertainty implicit {label}", implicit_s, repeats, note=note),
    ]


def agreement_note(implicit: list[DepthStats], mc: list[DepthStats], n_codes: int) -> str:
    """ "MC M=10 over the N pixels every code hit: median ratio ..., Pearson ..., Spearman ... (...)"."""
    agreement = std_agreement(pooled_stats(implicit), pooled_stats(mc))
    return (
        f"MC M={n_codes} over the {agreement['pixels']} pixels every code hit: median ratio "
        f"{agreement['median_ratio']:.3f}, Pearson {agreement['pearson']:.3f}, Spearman "
        f"{agreement['spearman']:.3f} (MC's own std error ~{1 / math.sqrt(2 * (n_codes - 1)):.0%})"
    )
