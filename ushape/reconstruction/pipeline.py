"""Images -> per-view latent Gaussians -> fused code -> mesh with per-vertex SDF std, depth maps, summary.

Cameras for the depth maps: an input that is a render of our world (`renders/<id>/NN.png` with
`views.npz` beside it) is traced from its own camera. A user photo has no pose, so it is traced
from a canonical R2N2-like camera: azimuth 45, elevation 27.5 deg (the middle of R2N2's range),
distance 2.8 = 0.8 * 1.75 / 0.5 (R2N2's mean distance ratio in our unit-sphere frame), 49.13 deg
field of view. Its depth map shows the reconstruction's uncertainty from that fixed viewpoint,
not aligned with the photo. So does a render whose views.npz cannot be read, with a warning naming
the file: the camera only places the depth map, the shape does not depend on it.
"""

from __future__ import annotations

import logging
import time
import zipfile
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np
import torch
import trimesh
from torch import Tensor

from ushape import atomic
from ushape.data.cameras import R2N2_FOV_DEG, look_at
from ushape.data.layout import VIEWS_FILE
from ushape.decoder.latent_gaussian import is_full_covariance, latent_trace
from ushape.decoder.precision import check_precision, resolve_precision
from ushape.decoder.query import code_sdf_fn, decoder_device, frozen
from ushape.fusion.rules import FusedCode
from ushape.mesh.extraction import ExtractionStats, extract_mesh
from ushape.propagation.depth_implicit import DEPTH_METHODS, depth_stats
from ushape.propagation.mesh import METHODS, vertex_uncertainty
from ushape.propagation.monte_carlo import sample_codes
from ushape.propagation.sphere_tracing import DepthStats
from ushape.recalibration import apply_temperature
from ushape.recalibration.refine_information import seen_floor_variance
from ushape.reconstruction.export import DEFAULT_CMAP, coloured_mesh, write_mesh_files
from ushape.reconstruction.figures import depth_figure, overview_figure
from ushape.reconstruction.predictor import Predictor
from ushape.reconstruction.refine_calibration import read_refinement_calibration
from ushape.reconstruction.visibility import hidden_over_visible, seen_by_views
from ushape.refinement import MODES as REFINE_MODES
from ushape.refinement import ObservationSettings, ObservedView, RefineSettings, refine
from ushape.refinement.inputs import input_views

log = logging.getLogger(__name__)
# What summary.json's refinement record keeps of the calibration it applied (reconstruct.py --fit-refinement).
APPLIED = ("information_scale", "sdf_temperature", "sdf_floor", "seen", "size", "n_shapes")

CANONICAL_CAMERA = {"azimuth_deg": 45.0, "elevation_deg": 27.5, "distance": 2.8, "fov_deg": R2N2_FOV_DEG}
SUMMARY_FILE = "summary.json"

Fusion = Callable[[Tensor, Tensor], FusedCode]  # (mu [V, D], var [V, D]) -> FusedCode (var [D] or [D, D])


@dataclass(frozen=True)
class ReconstructionSettings:
    """What `reconstruct` does beyond the inputs; every field has a command-line flag in reconstruct.py."""

    resolution: int = 128
    uncertainty: str = "linearised"
    n_samples: int = 10  # codes for MC vertex uncertainty
    depth_size: int = 64
    depth_method: str = "implicit"  # "implicit": trace the mean code once; "mc": trace depth_codes sampled codes
    depth_codes: int = 10  # M codes sphere-traced per view by depth_method "mc"
    depth_steps: int = 50
    std_max: float | None = None
    cmap: str = DEFAULT_CMAP
    seed: int = 0
    refine: str | None = None  # "masks" | "depth": refine the fused code on the views (ushape.refinement)
    refine_size: int = 32  # rays per image side the refinement compares
    refine_starts: int = 0  # prior draws scored beside the fused mean; the LM starts from the lowest energy
    # The decoder's: fp32, bf16, or auto (bf16 where faster: AMX CPUs, CUDA >= 8.0). Under bf16 the mesh
    # is searched in bf16 and placed by fp32 values; linearised and implicit stds use bf16 passes;
    # Monte Carlo stds stay fp32.
    precision: str = "auto"


def view_camera(path: Path, size: int) -> tuple[np.ndarray, np.ndarray, str]:
    """(K [3,3] for a size x size image, world_to_cam [4,4], "render" | "canonical") for one input image."""
    views = path.parent / VIEWS_FILE
    if views.is_file() and path.stem.isdigit():
        try:
            with np.load(views) as cams:
                view = int(path.stem)
                if view < len(cams["K"]):
                    K = cams["K"][view].astype(np.float64)
                    render_size = 2.0 * K[0, 2]  # the principal point is the image centre
                    scale = np.diag([size / render_size, size / render_size, 1.0])
                    return scale @ K, cams["world_to_cam"][view].astype(np.float64), "render"
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as err:
            # Only the depth map needs the camera: the shape is the same, seen from the canonical view.
            log.warning(
                "camera file %s of %s cannot be read (%s: %s): its depth map is traced from the canonical "
                "camera instead; re-render the view or delete the file",
                views,
                path,
                type(err).__name__,
                err,
            )
    c = CANONICAL_CAMERA
    K, w2c = look_at(c["azimuth_deg"], c["elevation_deg"], c["distance"], c["fov_deg"], size)
    return K, w2c, "canonical"


class Timer:
    """Wall-clock seconds per named stage."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        yield
        self.seconds[name] = round(self.seconds.get(name, 0.0) + time.perf_counter() - start, 4)


def reconstruct(
    predictor: Predictor,
    inputs: Sequence[str | Path],
    fusion: Fusion,
    out_dir: str | Path,
    settings: ReconstructionSettings = ReconstructionSettings(),
    observations: Sequence[ObservedView | None] | None = None,
) -> dict[str, Any]:
    """Run the whole reconstruction of one object from its views and write every output; returns the summary.

    With settings.refine, the fused code is refined on the views' masks (and depth): `observations`, one
    per input image (None: no camera), or by default the cameras, masks and depth of renders of the world.
    The mesh, its std and the depth maps then come from the full-covariance posterior.
    """
    if settings.refine is not None and settings.refine not in REFINE_MODES:
        raise ValueError(f"refine must be one of {REFINE_MODES} or None, got {settings.refine!r}")
    if settings.refine_starts < 0:
        raise ValueError(f"refine_starts (--refine-starts) must be >= 0, got {settings.refine_starts}")
    if settings.uncertainty not in METHODS:
        raise ValueError(f"uncertainty must be one of {METHODS}, got {settings.uncertainty!r}")
    if settings.depth_method not in DEPTH_METHODS:
        raise ValueError(f"depth_method must be one of {DEPTH_METHODS}, got {settings.depth_method!r}")
    check_precision(settings.precision)
    timer, generator = Timer(), torch.Generator().manual_seed(settings.seed)
    with timer("load_images"):
        images, paths, skipped = predictor.load_images(list(inputs))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with timer("encode"):
        mu, var = predictor.encode(images)
    with timer("fuse"):
        fused = fusion(mu, var)
    decoder = predictor.decoder
    precision, why = resolve_precision(settings.precision, decoder_device(decoder))
    bf16 = precision == "bf16"
    # Monte Carlo stays fp32: its std is the spread of M rounded SDFs, and bf16's rounding floor moved
    # the vertex std of the trained quickstart decoder by 0.4 % at latent var 0.01, 1.0 % at 1e-3 and
    # 1.9 % at 1e-4 (median): the 2 % contract would break for a confident posterior.
    prior, refinement, refined_views = fused, None, []
    if settings.refine is not None:
        with timer("refine"):
            calibration = read_refinement_calibration(predictor.checkpoint, settings.refine)
            fused, refinement, refined_views = refined(
                decoder, fused, inputs, paths, observations, settings, calibration
            )
    with timer("mesh"):
        mesh, stats = mean_mesh(decoder, fused.mu, settings.resolution, bf16)
    with timer("vertex_uncertainty"):
        vertices = torch.as_tensor(np.asarray(mesh.vertices), dtype=torch.float32)
        std = vertex_uncertainty(
            decoder,
            fused.mu,
            fused.var,
            vertices,
            settings.uncertainty,
            settings.n_samples,
            generator,
            bf16=bf16 and settings.uncertainty == "linearised",
        )
        floors = seen_floors(refinement)
        sdf_t = sdf_temperature(fusion, predictor, refinement)
        if floors is not None:  # the refinement's fit with a floor where the views saw the surface, one where not
            seen_vertices = torch.as_tensor(seen_by_views(mesh, mesh.vertices, refined_views, floors["tolerance"]))
            variance = seen_floor_variance(
                std.double().square(), seen_vertices, sdf_t, floors["floor_seen"], floors["floor_unseen"]
            )
            std = variance.sqrt().float()
            refinement["seen_vertices"] = float(seen_vertices.float().mean()) if len(seen_vertices) else None
        elif sdf_t is not None:  # the SDF-space recalibration (`fit_and_store_temperature`)
            std = apply_temperature(std.square(), sdf_t).sqrt()
        std = std.numpy()
    with timer("write_mesh"):
        files = write_mesh_files(mesh, std, out_dir, "mesh", settings.std_max, settings.cmap)
    with timer("overview_figure"):
        overview = out_dir / "overview.png"
        shown = coloured_mesh(mesh, std, float(files["std_max"]), settings.cmap)
        overview_figure(images, shown, overview, float(files["std_max"]), settings.cmap, fused.kept.tolist())
    cameras = [view_camera(path, settings.depth_size) for path in paths]
    with timer("depth_uncertainty"):
        views = depth_maps(predictor, fused, cameras, settings, generator, bf16 and settings.depth_method == "implicit")
    with timer("depth_files"):  # the figures cost about as much as the implicit depth itself
        depth = write_depth_maps(views, images, cameras, out_dir, settings)
    with timer("visibility"):  # only where the view's camera is known: a render of the world
        seen = [hidden_over_visible(mesh, std, w2c) if kind == "render" else None for _, w2c, kind in cameras]
    return write_summary(
        out_dir,
        predictor,
        fusion,
        settings,
        paths,
        skipped,
        var,
        prior,
        mesh,
        std,
        stats,
        files,
        overview,
        depth,
        seen,
        timer.seconds,
        refinement,
        {"requested": settings.precision, "resolved": precision, "why": why},
    )


def sdf_temperature(fusion: Fusion, predictor: Predictor, refinement: dict | None = None) -> float | None:
    """The factor on the SDF variance propagated from the code meshed: a refined code's, the refinement's own
    where --fit-refinement fitted it (`refinement["calibration"]`); a fused code's, the fusion rule's own where
    it has one (`shared`, fitted on val on its fused variance); else the predictor's single-view one."""
    if refinement is not None:
        calibration, floors = refinement.get("calibration"), seen_floors(refinement)
        if floors is not None:  # fitted with the seen / unseen floors, as the mesh's std is drawn
            return floors["sdf_temperature"]
        return predictor.sdf_temperature if calibration is None else calibration["sdf_temperature"]
    own = getattr(fusion, "sdf_temperature", None)
    return predictor.sdf_temperature if own is None else own


def seen_floors(refinement: dict | None) -> dict | None:
    """The refinement's fitted variance with its floors where the views saw the surface and where they did not
    (`refine_calibration`'s "seen"), or None: no refinement, a fallback to the prior, or a fit stored before it."""
    if refinement is None or refinement.get("fallback") is not None:
        return None
    return (refinement.get("calibration") or {}).get("seen")


def sdf_floor(fusion: Fusion, refinement: dict | None = None) -> float | None:
    """The std added to that SDF variance, T var + floor^2: the refinement's fitted floor, or the fusion rule's;
    None where the refinement's seen / unseen floors differ per vertex (they are in the mesh's std)."""
    if refinement is not None:
        if seen_floors(refinement) is not None:
            return None
        return (refinement.get("calibration") or {}).get("sdf_floor") or None
    return getattr(fusion, "sdf_floor", None)


def refined(
    decoder: torch.nn.Module,
    fused: FusedCode,
    inputs: Sequence[str | Path],
    paths: Sequence[Path],  # the inputs that could be read
    observations: Sequence[ObservedView | None] | None,  # one per input
    settings: ReconstructionSettings,
    calibration: dict[str, Any] | None = None,  # --fit-refinement's fit for this mode (None: none)
) -> tuple[FusedCode, dict[str, Any], list[ObservedView]]:
    """The fused code refined on the views (FusedCode with var the full covariance [D, D]), its record and the
    views it was refined on; with a calibration, the posterior at its information scale s, and the record
    carries the calibration."""
    if observations is None:
        views = input_views(paths)
    elif len(observations) != len(inputs):
        raise ValueError(f"{len(observations)} observed views for {len(inputs)} input images: pass one per image")
    else:
        by_input = dict(zip((Path(i) for i in inputs), observations))
        views = [by_input[Path(p)] for p in paths]
    scale = 1.0 if calibration is None else float(calibration["information_scale"])
    if calibration is not None and calibration.get("size") != settings.refine_size:
        log.warning(
            "the refinement's calibration was fitted at %s rays a side, this refinement uses %d: refit with "
            "`reconstruct.py --fit-refinement %s --refine-size %d`",
            calibration.get("size"),
            settings.refine_size,
            settings.refine,
            settings.refine_size,
        )
    observation = ObservationSettings(size=settings.refine_size)
    options = RefineSettings(
        mode=settings.refine, observation=observation, information_scale=scale, starts=settings.refine_starts
    )
    posterior = refine(decoder, fused.mu, fused.var, views, options)
    record = {"mode": settings.refine, "starts": settings.refine_starts, **posterior.record()}
    record["views_with_camera"] = sum(v is not None for v in views)
    record["calibration"] = None if calibration is None else {k: calibration.get(k) for k in APPLIED}
    record["mu"] = posterior.mu.tolist()
    views = [v for v in views if v is not None]
    if posterior.fallback is not None:  # the prior exactly, in its own (diagonal) form
        return fused, record, views
    return FusedCode(posterior.mu, posterior.cov, fused.kept), record, views


def mean_mesh(
    decoder: torch.nn.Module, mu: Tensor, resolution: int, bf16: bool = False
) -> tuple[trimesh.Trimesh, ExtractionStats]:
    """Coarse-to-fine mesh of the code mu [D]; under bf16 its vertices are still placed by fp32 values."""
    coarse = min(32, resolution)  # extract_mesh's default coarse grid, capped for small meshes
    with frozen(decoder):
        exact = code_sdf_fn(decoder, mu) if bf16 else None
        return extract_mesh(
            code_sdf_fn(decoder, mu, bf16), resolution, "coarse_to_fine", coarse_resolution=coarse, surface_fn=exact
        )


def depth_maps(
    predictor: Predictor,
    fused: FusedCode,
    cameras: Sequence[tuple[np.ndarray, np.ndarray, str]],  # view_camera(path, settings.depth_size) per view
    settings: ReconstructionSettings,
    generator: torch.Generator,
    bf16: bool = False,
) -> list[DepthStats]:
    """Per view: depth mean/std [S, S] of the fused Gaussian's surface along the view's camera.

    settings.depth_method "implicit" traces the mean code for all views at once and differentiates the hit
    depth (depth_implicit); "mc" traces M = settings.depth_codes codes drawn once from the fused Gaussian
    (the same codes for every view).
    """
    mc = settings.depth_method == "mc"
    codes = sample_codes(fused.mu, fused.var, settings.depth_codes, generator) if mc else None
    size = settings.depth_size
    return depth_stats(
        predictor.decoder,
        fused.mu,
        fused.var,
        [c[:2] for c in cameras],
        (size, size),
        settings.depth_method,
        codes,
        settings.depth_steps,
        bf16,
    )


def write_depth_maps(
    views: Sequence[DepthStats],
    images: Tensor,
    cameras: Sequence[tuple[np.ndarray, np.ndarray, str]],
    out_dir: Path,
    settings: ReconstructionSettings,
) -> list[dict[str, Any]]:
    """depth_<i>.npz (mean, std, hit_rate, K, world_to_cam) and depth_<i>.png per view; their summary records."""
    records = []
    for i, ((K, w2c, camera), stats) in enumerate(zip(cameras, views)):
        npz, png = out_dir / f"depth_{i:02d}.npz", out_dir / f"depth_{i:02d}.png"
        atomic.save_npz(
            npz, mean=stats.mean.numpy(), std=stats.std.numpy(), hit_rate=stats.hit_rate.numpy(), K=K, world_to_cam=w2c
        )
        depth_figure(images[i], stats, png, f"view {i} ({camera} camera, {settings.depth_method})")
        hit = stats.hit_rate > 0
        records.append(
            {
                "camera": camera,
                "method": settings.depth_method,
                "codes": settings.depth_codes if settings.depth_method == "mc" else None,
                "npz": str(npz),
                "png": str(png),
                "mean_depth_std": float(stats.std[hit].mean()) if hit.any() else None,
                "hit_pixels": int(hit.sum()),
            }
        )
    return records


def write_summary(
    out_dir: Path,
    predictor: Predictor,
    fusion: Fusion,
    settings: ReconstructionSettings,
    paths: Sequence[Path],
    skipped: Sequence[tuple[Path, str]],
    var: Tensor,
    fused: FusedCode,
    mesh: trimesh.Trimesh,
    std: np.ndarray,
    stats: Any,
    files: dict,
    overview: Path,
    depth: list[dict],
    seen: list[dict | None],
    seconds: dict[str, float],
    refinement: dict[str, Any] | None = None,
    precision: dict[str, str] | None = None,
) -> dict[str, Any]:
    """summary.json: inputs, per-view uncertainty (trace of var), fusion's kept views, the refinement's record
    (None without refinement), mesh, timings, paths, and the decoder's precision (requested, resolved, why)."""
    kept = set(fused.kept.tolist())
    summary = {
        "checkpoint": str(predictor.checkpoint),
        "temperature": predictor.temperature,
        "sdf_temperature": sdf_temperature(fusion, predictor, refinement),
        # The std the calibrated SDF variance adds, T var + floor^2 (fitted with T for the fusion rule, or for the
        # refinement); the same at every point, so the mesh's std files leave it out (None: no floor). A refinement
        # fitted with a floor where the views saw the surface and one where they did not puts those in the mesh's
        # std instead (refinement.calibration.seen, and the fraction of vertices seen, refinement.seen_vertices).
        "sdf_floor": sdf_floor(fusion, refinement),
        "fusion": getattr(fusion, "name", type(fusion).__name__),
        "fusion_calibration": getattr(fusion, "calibration", None),
        "uncertainty": settings.uncertainty,
        "depth_method": settings.depth_method,
        "precision": precision,
        "settings": asdict(settings),
        "views": [
            {
                "image": str(p),
                "trace_var": float(var[i].sum()),
                "kept": i in kept,
                "depth": depth[i],
                "visibility": seen[i],
            }
            for i, p in enumerate(paths)
        ],
        "skipped": [{"image": str(p), "reason": why} for p, why in skipped],
        "fused": {
            "trace_var": float(latent_trace(fused.var)),
            "covariance": "full" if is_full_covariance(fused.var) else "diagonal",
            "kept": sorted(kept),
            "mu": fused.mu.tolist(),
        },
        "mesh": {
            "vertices": len(mesh.vertices),
            "faces": len(mesh.faces),
            "std_mean": float(np.mean(std)),
            "std_max_value": float(np.max(std)),
            "decoder_evaluations": stats.evaluations,
            "dense_evaluations": stats.dense_evaluations,
        },
        "refinement": refinement,
        "files": {**files, "overview": str(overview)},
        "seconds": seconds,
    }
    atomic.write_json(out_dir / SUMMARY_FILE, summary)
    return summary
