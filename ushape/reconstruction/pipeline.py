"""Images -> per-view latent Gaussians -> fused code (refined on the views where asked) -> mesh with per-vertex
SDF std, depth maps along each view's camera, overview figure and summary.json (`reconstruct`)."""

from __future__ import annotations

import logging
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np
import torch
import trimesh
from torch import Tensor

from ushape import atomic
from ushape.decoder.latent_gaussian import is_full_covariance, latent_trace
from ushape.decoder.precision import check_precision, resolve_precision
from ushape.decoder.query import decoder_device
from ushape.fusion.rules import FusedCode
from ushape.propagation.depth_implicit import DEPTH_METHODS
from ushape.propagation.field import code_mesh
from ushape.propagation.mesh import METHODS
from ushape.reconstruction.export import coloured_mesh, write_mesh_files
from ushape.reconstruction.figures import overview_figure
from ushape.reconstruction.mesh_std import Fusion, mesh_std, sdf_distance_scale, sdf_floor, sdf_temperature
from ushape.reconstruction.out_dir import SUMMARY_FILE, claimed
from ushape.reconstruction.page import known_cameras, page_figures, reconstruction_page
from ushape.reconstruction.pose_calibration import pose_settings_for
from ushape.reconstruction.predictor import Predictor
from ushape.reconstruction.refine_calibration import read_refinement_calibration
from ushape.reconstruction.refined_code import r2n2_frame_of, refined
from ushape.reconstruction.settings import POSE_CHOICES, ReconstructionSettings
from ushape.reconstruction.view_depth import depth_maps, view_camera, write_depth_maps
from ushape.reconstruction.visibility import hidden_over_visible
from ushape.refinement import MODES as REFINE_MODES
from ushape.refinement import ObservedView
from ushape.refinement.posterior import MIN_SIZE as REFINE_MIN_SIZE

log = logging.getLogger(__name__)


class Timer:
    """Wall-clock seconds per named stage."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        yield
        self.seconds[name] = round(self.seconds.get(name, 0.0) + time.perf_counter() - start, 4)


def check_settings(settings: ReconstructionSettings) -> None:
    """A ValueError naming the setting (and its reconstruct.py flag) that is out of range, before any work."""
    if settings.refine is not None and settings.refine not in REFINE_MODES:
        raise ValueError(f"refine must be one of {REFINE_MODES} or None, got {settings.refine!r}")
    if settings.pose not in POSE_CHOICES:
        raise ValueError(f"pose (--pose) must be one of {POSE_CHOICES}, got {settings.pose!r}")
    if settings.refine not in REFINE_MODES and (settings.pose == "estimate" or settings.relative_poses):
        raise ValueError(
            "the object's pose is estimated with its shape from masks (or masks and depth): --pose estimate and "
            "--relative-poses need --refine masks or --refine depth"
        )
    if settings.pose == "given" and settings.relative_poses:
        raise ValueError("--relative-poses is read by the pose estimation: drop --pose given")
    if not 0 < settings.fov < 180:
        raise ValueError(f"fov (--fov) must be in (0, 180) degrees, got {settings.fov}")
    if settings.elevation is not None and not -90 < settings.elevation < 90:
        raise ValueError(f"elevation (--elevation) must be in (-90, 90) degrees, got {settings.elevation}")
    if settings.tilt_std is not None and settings.tilt_std <= 0:
        raise ValueError(f"tilt_std (--tilt-std) must be > 0 degrees (leave it out for the rotation's), got "
                         f"{settings.tilt_std}")  # fmt: skip
    if settings.refine_starts < 0:
        raise ValueError(f"refine_starts (--refine-starts) must be >= 0, got {settings.refine_starts}")
    if settings.refine_size < REFINE_MIN_SIZE:
        raise ValueError(
            f"refine_size (--refine-size) must be >= {REFINE_MIN_SIZE} rays a side, got {settings.refine_size}"
        )
    if settings.uncertainty not in METHODS:
        raise ValueError(f"uncertainty must be one of {METHODS}, got {settings.uncertainty!r}")
    if settings.depth_method not in DEPTH_METHODS:
        raise ValueError(f"depth_method must be one of {DEPTH_METHODS}, got {settings.depth_method!r}")
    check_precision(settings.precision)


@dataclass
class Encoded:
    """What the views gave: their images [V, 3, H, W], the paths read and those skipped (with why), each view's
    latent variance [V, D], the fused Gaussian (`prior`) and the code meshed (`fused`: the prior, or the prior
    refined on the views, with the refinement's record and the views it was refined on)."""

    images: Tensor
    paths: list[Path]
    skipped: list[tuple[Path, str]]
    var: Tensor
    prior: FusedCode
    fused: FusedCode
    refinement: dict[str, Any] | None = None
    refined_views: list[ObservedView] = field(default_factory=list)


def encode_views(
    predictor: Predictor,
    inputs: Sequence[str | Path],
    fusion: Fusion,
    settings: ReconstructionSettings,
    observations: Sequence[ObservedView | None] | None,
    timer: Timer,
    masks: Sequence[str | Path] | None = None,
) -> Encoded:
    """Load, encode and fuse the views (cut out by their masks where given); refine the fused code on them where
    settings.refine asks."""
    with timer("load_images"):
        images, paths, skipped = predictor.load_images(list(inputs), masks)
    with timer("encode"):
        mu, var = predictor.encode(images)
    with timer("fuse"):
        fused = fusion(mu, var)
    encoded = Encoded(images, paths, skipped, var, fused, fused)
    if settings.refine is not None:
        with timer("refine"):
            calibration = read_refinement_calibration(predictor.checkpoint, settings.refine)
            encoded.fused, encoded.refinement, encoded.refined_views = refined(
                predictor.decoder,
                fused,
                inputs,
                paths,
                observations,
                settings,
                calibration,
                r2n2_frame_of(predictor),
                mask_files(inputs, paths, masks),
                lambda: predictor.azimuth_log_probs(images),
                pose_settings_for(predictor.checkpoint, settings.refine or "masks"),
            )
    return encoded


def mask_files(inputs, paths, masks) -> list[Path] | None:
    """The mask files of the inputs that could be read (paths), in their order; None where none were given."""
    if masks is None:
        return None
    by_input = dict(zip((Path(i) for i in inputs), masks))
    return [Path(by_input[Path(p)]) for p in paths]


def reconstruct(
    predictor: Predictor,
    inputs: Sequence[str | Path],
    fusion: Fusion,
    out_dir: str | Path,
    settings: ReconstructionSettings = ReconstructionSettings(),
    observations: Sequence[ObservedView | None] | None = None,
    masks: Sequence[str | Path] | None = None,
) -> dict[str, Any]:
    """Run the whole reconstruction of one object from its views and write every output; returns the summary.

    masks: one mask file per input (white = object): the object is cut out of its image by it before encoding.

    With settings.refine, the fused code is refined on the views' masks (and depth): `observations`, one
    per input image (None: no camera), or by default the cameras, masks and depth of renders of the world.
    The mesh, its std and the depth maps then come from the full-covariance posterior.
    """
    check_settings(settings)
    timer, generator = Timer(), torch.Generator().manual_seed(settings.seed)
    encoded = encode_views(predictor, inputs, fusion, settings, observations, timer, masks)
    with claimed(out_dir):  # made once the views are read: unreadable inputs leave nothing behind
        return write_outputs(predictor, fusion, settings, encoded, Path(out_dir), timer, generator)


def write_outputs(
    predictor: Predictor,
    fusion: Fusion,
    settings: ReconstructionSettings,
    encoded: Encoded,
    out_dir: Path,
    timer: Timer,
    generator: torch.Generator,
) -> dict[str, Any]:
    """The mesh of the fused (or refined) code with its std, the depth maps and summary.json, into out_dir."""
    fused, images = encoded.fused, encoded.images
    precision, why = resolve_precision(settings.precision, decoder_device(predictor.decoder))
    bf16 = precision == "bf16"
    with timer("mesh"):
        mesh, stats = code_mesh(predictor.decoder, fused.mu, settings.resolution, "coarse_to_fine", bf16)
    with timer("vertex_uncertainty"):
        # Monte Carlo stays fp32: its std is the spread of M rounded SDFs, and bf16's rounding floor moved
        # the vertex std of the trained quickstart decoder by 0.4 % at latent var 0.01, 1.0 % at 1e-3 and
        # 1.9 % at 1e-4 (median): the 2 % contract would break for a confident posterior.
        bf16_std = bf16 and settings.uncertainty == "linearised"
        std = mesh_std(
            predictor, fusion, fused, mesh, settings, generator, encoded.refinement, encoded.refined_views, bf16_std
        )
    files = write_mesh_outputs(mesh, std, images, fused.kept.tolist(), out_dir, settings, timer)
    cameras = [view_camera(path, settings.depth_size) for path in encoded.paths]
    with timer("depth_uncertainty"):
        views = depth_maps(predictor, fused, cameras, settings, generator, bf16 and settings.depth_method == "implicit")
    with timer("depth_files"):  # the figures cost about as much as the implicit depth itself
        depth = write_depth_maps(views, images, cameras, out_dir, settings)
    with timer("visibility"):  # only where the view's camera is known: a render of the world
        seen = [hidden_over_visible(mesh, std, w2c) if kind == "render" else None for _, w2c, kind in cameras]
    precision_record = {"requested": settings.precision, "resolved": precision, "why": why}
    args = (predictor, fusion, settings, encoded, mesh, std, stats, files, depth, seen, timer.seconds)
    summary = summary_record(*args, precision_record)
    with timer("report"):
        prior = None
        if encoded.refinement is not None and not encoded.refinement.get("fallback"):
            prior_mesh, _ = code_mesh(predictor.decoder, encoded.prior.mu, settings.resolution, "coarse_to_fine", bf16)
            prior_std = mesh_std(predictor, fusion, encoded.prior, prior_mesh, settings, generator, None, [], bf16_std)
            prior = (prior_mesh, prior_std)
        known = known_cameras(encoded, cameras, settings.depth_size)
        page = reconstruction_page(out_dir, encoded, mesh, std, files, known, page_figures(summary), prior)
    summary["files"]["report"] = str(page)
    summary["seconds"] = timer.seconds
    atomic.write_json(out_dir / SUMMARY_FILE, summary)
    return summary


def write_mesh_outputs(
    mesh: trimesh.Trimesh,
    std: np.ndarray,  # [V] the vertices' SDF std
    images: Tensor,  # [V, 3, H, W] the input views
    kept: list[int],  # the views the fusion kept
    out_dir: Path,
    settings: ReconstructionSettings,
    timer: Timer,
) -> dict[str, Any]:
    """The mesh's files (export.write_mesh_files) and overview.png (the views beside the mesh coloured by its
    std); their paths, with "overview"."""
    with timer("write_mesh"):
        files = write_mesh_files(mesh, std, out_dir, "mesh", settings.std_max, settings.cmap)
    with timer("overview_figure"):
        overview = out_dir / "overview.png"
        shown = coloured_mesh(mesh, std, float(files["std_max"]), settings.cmap)
        overview_figure(images, shown, overview, float(files["std_max"]), settings.cmap, kept)
    return {**files, "overview": str(overview)}


def summary_record(
    predictor: Predictor,
    fusion: Fusion,
    settings: ReconstructionSettings,
    encoded: Encoded,
    mesh: trimesh.Trimesh,
    std: np.ndarray,
    stats: Any,
    files: dict,  # the mesh's files and the overview figure
    depth: list[dict],
    seen: list[dict | None],
    seconds: dict[str, float],
    precision: dict[str, str] | None = None,
) -> dict[str, Any]:
    """What summary.json holds (write_outputs writes it once the page is made): inputs, per-view uncertainty
    (trace of var), fusion's kept views, the refinement's record (None without refinement), mesh, timings,
    paths, and the decoder's precision (requested, resolved, why)."""
    fused, refinement, var, paths = encoded.prior, encoded.refinement, encoded.var, encoded.paths
    kept = set(fused.kept.tolist())
    summary = {
        "model": predictor.model_name,  # the shipped model reconstructed with (None: a run's checkpoint)
        "checkpoint": str(predictor.checkpoint),
        "temperature": predictor.temperature,
        "sdf_temperature": sdf_temperature(fusion, predictor, refinement),
        # The std the calibrated SDF variance adds, T var + floor^2 (fitted with T for the fusion rule, or for the
        # refinement); the same at every point, so the mesh's std files leave it out (None: no floor). A refinement
        # fitted with a floor where the views saw the surface and one where they did not puts those in the mesh's
        # std instead (refinement.calibration.seen, and the fraction of vertices seen, refinement.seen_vertices).
        "sdf_floor": sdf_floor(fusion, refinement),
        # The fusion rule's term in the distance from the predicted surface, (b |mean|)^2 (None: none); ~0 on
        # the mesh, so its std files leave it out too; away from the surface the SDF std grows with it.
        "sdf_distance_scale": sdf_distance_scale(fusion, refinement),
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
                # what the refinement took of this view ({"used": "masks" | "masks+depth" | None, "fallback": why
                # less than asked}); None without refinement
                "refined_on": refinement["views"][i] if refinement and i < len(refinement.get("views", [])) else None,
            }
            for i, p in enumerate(paths)
        ],
        "skipped": [{"image": str(p), "reason": why} for p, why in encoded.skipped],
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
        "files": files,
        "seconds": seconds,
    }
    return summary
