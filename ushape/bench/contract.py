"""bf16 against fp32 for the reconstruction's outputs: what the precision contract bounds, and its timed rows.

The contract (what `precision: auto` may only pick bf16 under): the mesh agrees with the fp32 mesh
(DeepSDF Chamfer <= 1e-5 in the unit-sphere frame, IoU at 64^3 >= 0.995), the vertex and depth std
agree within 2 % (median relative difference), and the evaluation's IoU moves by at most 0.002.
The last is bounded without a ground truth: the Jaccard distance 1 - IoU is a metric, so for any
ground truth G, |IoU(A, G) - IoU(B, G)| <= 1 - IoU(A, B); A and B are the two predictions voxelised
as the evaluation voxelises them (32^3 in each mesh's box frame, by its own SDF grid).

Vertex stds are compared at the fp32 mesh's vertices (both paths evaluated there), depth stds at the
pixels both paths hit. Two meshes with the same faces and vertices within FP32_ROUNDING count as the same
mesh: the fp32 decoder's own values move in their last bits with the batch it is evaluated in and the
number of threads (measured on a 2-core Xeon with AMX, 2 threads: up to 7e-7 on a vertex), which is not
what bf16 changes.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch
from torch import Tensor, nn

from ushape.bench.timing import Measurement, interleaved
from ushape.evaluation.code_metrics import grid_inside_fn
from ushape.mesh.extraction import marching_cubes
from ushape.metrics.pix3d import PIX3D_VOXELS, box_frame, voxel_iou, voxelise
from ushape.metrics.reconstruction import EmptyOccupancyError, chamfer_deepsdf, mesh_inside_fn, volumetric_iou
from ushape.propagation.depth_implicit import depth_uncertainty_implicit_views
from ushape.propagation.field import code_mesh, surface_field
from ushape.propagation.mesh import vertex_uncertainty

LIMITS = {"chamfer": 1e-5, "iou": 0.995, "vertex_std": 0.02, "depth_std": 0.02, "eval_iou": 0.002}
EVAL_RESOLUTION = 64  # protocol=paper's mesh grid
FP32_ROUNDING = 1e-5  # vertex coordinates (the cube is [-1, 1]^3) two fp32 evaluations of one mesh may differ by
PRECISION_ROW = "mesh with uncertainty (c2f + linearised)"


@dataclass(frozen=True)
class Contract:
    """One path against fp32; `met` compares each figure with LIMITS (iou: at least, the others: at most)."""

    chamfer: float
    iou: float
    vertex_std: float  # median |std - std_fp32| / std_fp32 over the fp32 mesh's vertices
    depth_std: float | None  # the same over the pixels both paths hit (None: no cameras given)
    eval_iou: float  # bound on the change of the evaluation's IoU against any ground truth

    def met(self) -> bool:
        depth_ok = self.depth_std is None or self.depth_std <= LIMITS["depth_std"]
        return (
            self.chamfer <= LIMITS["chamfer"]
            and self.iou >= LIMITS["iou"]
            and self.vertex_std <= LIMITS["vertex_std"]
            and self.eval_iou <= LIMITS["eval_iou"]
            and depth_ok
        )

    def text(self) -> str:
        depth = "" if self.depth_std is None else f", depth std {self.depth_std:.2%}"
        verdict = "met" if self.met() else "MISSED"
        return (
            f"vs fp32: Chamfer {self.chamfer:.2g}, IoU64 {self.iou:.4f}, vertex std {self.vertex_std:.2%}{depth}, "
            f"eval IoU change <= {self.eval_iou:.4f} (contract {verdict})"
        )


def median_relative(a: Tensor, reference: Tensor) -> float:
    """Median of |a - reference| / reference where reference > 0."""
    a, reference = a.double().flatten(), reference.double().flatten()
    keep = torch.isfinite(a) & torch.isfinite(reference) & (reference > 0)
    return float(((a[keep] - reference[keep]).abs() / reference[keep]).median()) if keep.any() else float("nan")


def eval_iou_change_bound(decoder: nn.Module, code: Tensor, bf16: bool, resolution: int = EVAL_RESOLUTION) -> float:
    """1 - IoU of the evaluation's 32^3 voxels of the fp32 and of the bf16 prediction (see the module's doc)."""
    occupancies = []
    for half in (False, bf16):
        grid = surface_field(decoder, code, resolution, bf16=half)
        frame = box_frame(marching_cubes(grid).vertices)
        occupancies.append(voxelise(grid_inside_fn(grid), frame, PIX3D_VOXELS))
    return 1.0 - voxel_iou(*occupancies)


def depth_std_difference(
    decoder: nn.Module, code: Tensor, var: Tensor, cameras: Sequence[tuple], size: int, bf16: bool
) -> float:
    """Median relative difference of the implicit depth std maps (bf16 trace vs fp32) over pixels both hit."""
    maps = [
        depth_uncertainty_implicit_views(decoder, code, var, cameras, (size, size), bf16=half) for half in (False, bf16)
    ]
    reference = torch.stack([m.std for m in maps[0]])
    other = torch.stack([m.std for m in maps[1]])
    return median_relative(other, reference)


def same_mesh(mesh, reference) -> bool:
    """The same faces and every vertex within FP32_ROUNDING of the reference's."""
    if len(mesh.vertices) != len(reference.vertices) or not np.array_equal(mesh.faces, reference.faces):
        return False
    return bool(np.allclose(mesh.vertices, reference.vertices, rtol=0.0, atol=FP32_ROUNDING))


def mesh_iou(reference, mesh, resolution: int = 64) -> float:
    """Volumetric IoU of two meshes at resolution^3; NaN (the contract then reads as missed) where neither
    encloses any grid point, e.g. two open meshes whose ray-parity inside tests are empty."""
    try:
        return volumetric_iou(mesh_inside_fn(reference), mesh_inside_fn(mesh), resolution)
    except EmptyOccupancyError:
        return float("nan")


def contract(
    decoder: nn.Module,
    code: Tensor,  # [D]
    var: Tensor,  # [D]
    resolution: int = 128,
    bf16: bool = True,
    cameras: Sequence[tuple] = (),
    depth_size: int = 32,
    depth_var: Tensor | None = None,  # [D] of the depth maps (default var)
) -> Contract:
    """The contract's figures for the reconstruction in bf16 (or fp32: no difference) against fp32."""
    reference, _ = code_mesh(decoder, code, resolution, "coarse_to_fine")
    mesh, _ = code_mesh(decoder, code, resolution, "coarse_to_fine", bf16)
    vertices = torch.as_tensor(np.asarray(reference.vertices), dtype=torch.float32)
    std32 = vertex_uncertainty(decoder, code, var, vertices, "linearised")
    std = vertex_uncertainty(decoder, code, var, vertices, "linearised", bf16=bf16)
    same = same_mesh(mesh, reference)
    return Contract(
        chamfer=0.0 if same else chamfer_deepsdf(reference, mesh),
        iou=1.0 if same else mesh_iou(reference, mesh),
        vertex_std=median_relative(std, std32),
        depth_std=depth_std_difference(
            decoder, code, var if depth_var is None else depth_var, cameras, depth_size, bf16
        )
        if cameras
        else None,
        eval_iou=eval_iou_change_bound(decoder, code, bf16, min(resolution, EVAL_RESOLUTION)),
    )


def precision_rows(
    decoder: nn.Module,
    code: Tensor,
    var: Tensor,
    resolution: int,
    auto: str,
    repeats: int = 1,
    cameras: Sequence[tuple] = (),
    depth_size: int = 32,
    depth_var: Tensor | None = None,
) -> list[Measurement]:
    """ "mesh with uncertainty (c2f + linearised), <precision>" for fp32, bf16 and auto (resolved to `auto`).

    Each row times the coarse-to-fine mesh and the linearised vertex std together, as reconstruct.py runs
    them. The three are timed in interleaved rounds (`interleaved`), so a shared machine's drifting load
    reaches each alike; a row's seconds are its minimum over the rounds, its note gives the median and
    the load average before and after. The bf16 and auto rows' notes carry the contract's figures against fp32.
    """

    def run(bf16: bool):
        mesh, _ = code_mesh(decoder, code, resolution, "coarse_to_fine", bf16)
        vertices = torch.as_tensor(np.asarray(mesh.vertices), dtype=torch.float32)
        return mesh, vertex_uncertainty(decoder, code, var, vertices, "linearised", bf16=bf16)

    paths = {"fp32": False, "bf16": True, f"auto (-> {auto})": auto == "bf16"}
    load = os.getloadavg()[0]
    timings = interleaved({name: (lambda bf16=bf16: run(bf16)) for name, bf16 in paths.items()}, repeats)
    load = f"load {load:.1f} -> {os.getloadavg()[0]:.1f}"
    figures = contract(decoder, code, var, resolution, True, cameras, depth_size, depth_var)
    rows = []
    for name, bf16 in paths.items():
        timing = timings[name]
        mesh, _ = timing.result
        note = f"{len(mesh.vertices)} vertices; min of {repeats} interleaved, median {timing.median:.3g} s, {load}"
        if bf16:
            note += "; " + figures.text()
        elif name != "fp32":
            note += "; the fp32 computation itself"
        rows.append(Measurement(f"{PRECISION_ROW}, {name}", timing.minimum, repeats, note=note))
    return rows
