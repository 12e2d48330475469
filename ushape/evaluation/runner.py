"""What `python eval.py` does: find the runs, run every protocol for each encoder, gather the results.

Every encoder of the evaluation is scored on the same test views with the same crops, so ES, NLL
and L2 (FroDO*) runs land side by side in one set of tables.

The world evaluated may be another than the one the encoders trained on (`eval.py data=pix3d`:
real photos for encoders trained on ShapeNet). Its test shapes then have no stage-1 codes, so the
decoder's codes for them (the decoder-ceiling row, the latent-space scores) are latent-optimised
against it once, as stage 1 made its own val/test codes, and cached. A world that lists several
`mask_inputs` (Pix3D) evaluates each encoder once per input: every protocol with the first, the
single-view protocol (Table 1's extra rows) with the others.
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

from ushape.data.layout import WorldIndex
from ushape.decoder.artifacts import codes_file, load_codes
from ushape.evaluation import protocols as P
from ushape.evaluation.active import active_records, check_active_settings, save_active_sequence
from ushape.evaluation.depth_calibration import depth_calibration_rows
from ushape.evaluation.encoders import EncoderRun, load_encoder, mask_variants, split_codes
from ushape.evaluation.locality import has_cameras, locality_records, summarise_locality
from ushape.evaluation.showcase import save_showcase
from ushape.evaluation.uncertainty_protocol import (
    curves_to_json,
    error_tracking_row,
    latent_rows,
    pooled_error_tracking_row,
    sdf_rows,
    with_shape_accuracy,
)
from ushape.evaluation.view_calibration import view_calibration_protocol
from ushape.evaluation.views import encode_views
from ushape.propagation import SDF_CLAMP
from ushape.reconstruction.depth_implicit import DEPTH_METHODS

log = logging.getLogger(__name__)

PAPER_PROTOCOLS = ("single_view", "multi_view", "corrupted", "uncertainty", "locality", "depth")
# active: next-best-view (evaluation/active.py); view_calibration: Table V (evaluation/view_calibration.py). By name.
PROTOCOLS = (*PAPER_PROTOCOLS, "active", "view_calibration")
RESULT_ROW = "eval_row.json"
# The row lists every encoder contributes to an evaluation's result (concatenated over encoders).
ROW_KEYS = (
    "records",
    "uncertainty",
    "error_tracking",
    "locality",
    "locality_views",
    "depth",
    "active",
    "view_calibration",
    "rows",
)
RESULTS = "results.json"


@dataclass
class Settings:
    """What to evaluate and how finely (conf/eval.yaml's `settings`)."""

    split: str = "test"
    group_size: int = P.GROUP_SIZE
    table4_k: int = 4
    resolution: int = 64
    n_points: int = 1024
    bf16: bool = False
    single_view_scales: Sequence[float] = (1.0, 0.1, 0.01)
    single_view_views: int | None = None
    corrupted_scales: Sequence[float] = (0.8, 0.4, 0.2, 0.1, 0.01)
    sdf_points: int = 1024
    mc_samples: int = 10
    sdf_views: int | None = None
    sdf_clamp: float | None = SDF_CLAMP
    calibration_levels: int = 20
    locality_points: int = 2048
    locality_scale: float = 0.1
    locality_views: int | None = None
    depth_size: int = 48
    depth_views: int | None = 2
    depth_methods: Sequence[str] = ("implicit", "mc")
    depth_codes: int = 10
    depth_steps: int = 50
    max_shapes: int | None = None
    showcase_shapes: int = 2
    code_iterations: int = 800
    active_views: int = 6
    active_strategies: Sequence[str] = ("uncertainty", "unseen-uncertainty", "farthest", "random", "oracle")
    active_scales: Sequence[float] = (1.0, 0.1)
    active_shapes: int | None = None
    active_candidates: str = "auto"
    active_azimuths: int = 12
    active_elevations: int = 2
    seed: int = 0
    protocols: Sequence[str] = PAPER_PROTOCOLS

    def __post_init__(self) -> None:
        unknown = [p for p in self.protocols if p not in PROTOCOLS]
        if unknown:
            raise ValueError(f"unknown protocols {unknown}; choose from {PROTOCOLS}")
        if self.group_size < 1 or self.resolution < 8:
            raise ValueError("group_size must be >= 1 and resolution >= 8 (grid points per axis)")
        if not set(self.depth_methods) <= set(DEPTH_METHODS) or self.depth_size < 1 or self.depth_codes < 2:
            raise ValueError(
                f"depth_methods must be some of {DEPTH_METHODS}, depth_size >= 1 and depth_codes >= 2; "
                f"got {list(self.depth_methods)}, {self.depth_size}, {self.depth_codes}"
            )
        check_active_settings(self)


def evaluate_encoder(
    run: EncoderRun, settings: Settings, cache_dir: Path | None, setting: tuple[Callable, str, float] | None = None
) -> dict[str, list]:
    """Records of every protocol asked for, the uncertainty rows and curves, and the configured setting's row."""
    out: dict[str, Any] = {**{key: [] for key in ROW_KEYS}, "curves": {}}
    protocols = [p for p in settings.protocols if run.only is None or p in run.only]

    def encode(scale: float):
        return encode_views(
            run.predictor, run.world, run.keys, scale, settings.seed, cache_dir, mask_input=run.mask_input
        )

    groups = P.group_views(run.keys, settings.group_size, drop_short=bool(run.world.config.get("drop_short_instances")))
    rec = run.reconstructor
    if "single_view" in protocols or "corrupted" in protocols:
        scales = [1.0] if "corrupted" not in protocols else list(dict.fromkeys([1.0, *settings.single_view_scales]))
        for scale in scales:
            encodings = encode(scale).first_views(settings.single_view_views)
            out["records"] += P.single_view_records(run.spec, encodings, rec, scale, emd=scale == 1.0)
    if "multi_view" in protocols:
        methods = P.fusion_methods(run.spec.probabilistic, range(1, settings.group_size))
        out["records"] += P.multi_view_records(run.spec, encode(1.0), groups, methods, rec, 1.0)
    if "corrupted" in protocols:
        methods = P.fusion_methods(run.spec.probabilistic, [settings.table4_k])
        for scale in dict.fromkeys([*settings.corrupted_scales, *settings.single_view_scales]):
            if scale != 1.0 or "multi_view" not in protocols:
                out["records"] += P.multi_view_records(run.spec, encode(scale), groups, methods, rec, scale)
    if "uncertainty" in protocols:
        encodings = encode(1.0)
        codes = split_codes(run, settings, cache_dir)
        rows, latent_curves = latent_rows(run.spec, encodings, codes, settings.calibration_levels)
        sdf, sdf_curves = sdf_rows(
            run.spec,
            encodings,
            run.predictor.decoder,
            run.world,
            settings.sdf_points,
            settings.mc_samples,
            settings.sdf_clamp,
            settings.sdf_views,
            settings.calibration_levels,
            sdf_temperature=run.predictor.sdf_temperature,
        )
        out["uncertainty"] = rows + sdf
        scales = [1.0] + (list(settings.single_view_scales) if "corrupted" in protocols else [])
        tracking = [error_tracking_row(run.spec, encode(s), codes, s) for s in dict.fromkeys(scales)]
        tracking += [pooled_error_tracking_row(run.spec, encode(1.0), encode(s), codes, s) for s in scales if s != 1.0]
        out["error_tracking"] = with_shape_accuracy(tracking, out["records"])
        out["curves"] = {"latent": curves_to_json(latent_curves), "sdf": curves_to_json(sdf_curves)}
    if "locality" in protocols and not has_cameras(run.world, [k.shape_id for k in run.keys]):
        log.warning(
            "Table L skipped: the test renders of %s have no cameras (views.npz), so which parts a "
            "view hides or crops away is unknown",
            run.world.root,
        )
    elif "locality" in protocols:
        scale = settings.locality_scale
        out["locality_views"] = locality_records(
            run.spec,
            encode(1.0),
            encode(scale),
            run.predictor.decoder,
            run.world,
            scale,
            settings.seed,
            settings.locality_points,
            settings.locality_views,
        )
        out["locality"] = summarise_locality(out["locality_views"])
    if "active" in protocols:
        records, out["active"] = active_records(run, settings, split_codes(run, settings, cache_dir))
        out["records"] += records
    if "view_calibration" in protocols:
        codes = split_codes(run, settings, cache_dir)
        out["view_calibration"] = view_calibration_protocol(run, settings, encode(1.0), codes)
    if "depth" in protocols:
        out["depth"], curves = depth_protocol(run, settings, encode)
        out["curves"]["depth"] = curves_to_json(curves)
    if setting is not None and run.only is None:
        out["rows"].append(setting_row(run, settings, groups, encode, *setting))
    return out


def depth_protocol(run: EncoderRun, settings: Settings, encode: Callable) -> tuple[list[dict], dict]:
    """Table D's rows and curves: depth std against the true depth error along each test view's own camera."""
    if not has_cameras(run.world, [k.shape_id for k in run.keys]):
        log.warning("Table D skipped: the test renders of %s have no cameras (views.npz)", run.world.root)
        return [], {}
    return depth_calibration_rows(
        run.spec,
        encode(1.0),
        run.predictor.decoder,
        run.world,
        settings.depth_size,
        settings.depth_methods,
        settings.depth_codes,
        settings.depth_steps,
        settings.depth_views,
        settings.calibration_levels,
        settings.seed,
    )


def setting_row(
    run: EncoderRun, settings: Settings, groups, encode, fuse: Callable, method: str, min_scale: float
) -> dict:
    """One sweep row: single-view and fused multi-view IoU at the configured fusion rule and crop."""
    encodings = encode(min_scale)
    single = P.summarise(
        P.single_view_records(run.spec, encodings.first_views(settings.single_view_views), run.reconstructor, min_scale)
    )[0]
    fused = P.multi_view_records(run.spec, encodings, groups, {method: fuse}, run.reconstructor, min_scale, quiet=False)
    if not fused:
        log.warning(
            "no multi-view instance in %s (every shape has fewer than %d views): the row's multi-view cells are empty",
            run.world.root,
            settings.group_size,
        )
    multi = P.summarise(fused)[0] if fused else {"iou": math.nan, "cd": math.nan, "n": 0}
    return {
        "encoder": run.spec.name,
        "label": run.spec.label,
        "fusion": method,
        "min_scale": float(min_scale),
        "group_size": settings.group_size,
        "single_view_iou": single["iou"],
        "single_view_cd": single["cd"],
        "multi_view_iou": multi["iou"],
        "multi_view_cd": multi["cd"],
        "n_views": single["n"],
        "n_instances": multi["n"],
    }


def evaluate_runs(
    run_dirs: Sequence[str | Path],
    settings: Settings,
    cache_dir: Path | None = None,
    setting: tuple[Callable, str, float] | None = None,
    world_dir: str | Path | None = None,
    showcase_dir: Path | None = None,
    temperature: bool = False,
) -> dict[str, Any]:
    """Load every run folder's encoder and evaluate them all (see `evaluate_all`)."""
    if not run_dirs:
        raise ValueError("no runs to evaluate: pass runs=[<run folder>, ...] or sweep=<multirun folder>")
    taken: set[str] = set()
    opened: dict[Path, WorldIndex] = {}
    runs = [load_encoder(run_dir, settings, cache_dir, taken, world_dir, temperature, opened) for run_dir in run_dirs]
    variants = [(variant, run_dir) for run, run_dir in zip(runs, run_dirs) for variant in mask_variants(run)]
    result = evaluate_all([v for v, _ in variants], settings, cache_dir, setting, showcase_dir)
    for run, run_dir in variants:
        result["runs"][run.spec.name]["run_dir"] = str(run_dir)
    return result


def evaluate_all(
    runs: Sequence[EncoderRun],
    settings: Settings,
    cache_dir: Path | None = None,
    setting: tuple[Callable, str, float] | None = None,
    showcase_dir: Path | None = None,
) -> dict[str, Any]:
    """Every protocol for every encoder -> {records, summary, uncertainty, curves, rows, runs, settings, seconds}.

    With showcase_dir, the first shapes' reconstructions with uncertainty are saved there (see showcase).
    """
    started = time.time()
    result: dict[str, Any] = {
        **{key: [] for key in ROW_KEYS},
        "curves": {"latent": {}, "sdf": {}, "depth": {}},
        "runs": {},
    }
    for run in runs:
        log.info("evaluating %s on %d views of %s", run.spec.label, len(run.keys), run.world.root)
        part = evaluate_encoder(run, settings, cache_dir, setting)
        for key in ROW_KEYS:
            result[key] += part[key]
        for space, curves in part["curves"].items():
            result["curves"][space].update(curves)
        result["runs"][run.spec.name] = {
            "checkpoint": str(run.predictor.checkpoint),
            "world": str(run.world.root),
            "label": run.spec.label,
        }
        if showcase_dir is not None and settings.showcase_shapes > 0 and run.only is None:
            encodings = encode_views(
                run.predictor, run.world, run.keys, 1.0, settings.seed, cache_dir, mask_input=run.mask_input
            )
            save_showcase(
                run,
                encodings,
                showcase_dir,
                settings.group_size,
                settings.showcase_shapes,
                settings.resolution,
                settings.mc_samples,
            )
        if showcase_dir is not None and "active" in settings.protocols and run.only is None:
            save_active_sequence(run, settings, showcase_dir)
    if runs and "single_view" in settings.protocols:
        result["records"] += reference_rows(runs[0], settings, cache_dir)
    result["summary"] = P.summarise(result["records"])
    result["settings"] = {k: (list(v) if isinstance(v, (tuple, range)) else v) for k, v in vars(settings).items()}
    result["seconds"] = round(time.time() - started, 1)
    return result


def reference_rows(run: EncoderRun, settings: Settings, cache_dir: Path | None = None) -> list[dict]:
    """Table 1's reference rows from the first run's decoder: the test shapes' own codes and the mean code."""
    codes = split_codes(run, settings, cache_dir)
    train = load_codes(run.codes_dir / codes_file("train"))
    shape_ids = list(dict.fromkeys(k.shape_id for k in run.keys))
    return P.reference_records(codes, train, shape_ids, run.reconstructor)


def load_results(path: str | Path) -> dict[str, Any]:
    """An evaluation's results.json (a folder holding one, or the file)."""
    path = Path(path)
    path = path / RESULTS if path.is_dir() else path
    if not path.is_file():
        raise FileNotFoundError(f"no {RESULTS} at {path}: run `python eval.py` first")
    return json.loads(path.read_text())
