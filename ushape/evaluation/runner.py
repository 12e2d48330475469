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

import hashlib
import json
import logging
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

from ushape.data.layout import WorldIndex
from ushape.data.sdf_dataset import SDFSamplesDataset
from ushape.data.world import open_world
from ushape.decoder.artifacts import CodeTable, codes_file, load_codes, save_codes
from ushape.decoder.latent_optim import optimise_codes
from ushape.evaluation import protocols as P
from ushape.evaluation.active import active_records, check_active_settings, save_active_sequence
from ushape.evaluation.code_metrics import Reconstructor
from ushape.evaluation.depth_calibration import depth_calibration_rows
from ushape.evaluation.locality import has_cameras, locality_records, summarise_locality
from ushape.evaluation.showcase import save_showcase
from ushape.evaluation.uncertainty_protocol import (
    curves_to_json,
    decoder_dir_of,
    error_tracking_row,
    latent_rows,
    pooled_error_tracking_row,
    sdf_rows,
    with_shape_accuracy,
)
from ushape.evaluation.views import MASK_INPUTS, encode_views, test_views
from ushape.propagation import SDF_CLAMP
from ushape.reconstruction.depth_implicit import DEPTH_METHODS

log = logging.getLogger(__name__)

PAPER_PROTOCOLS = ("single_view", "multi_view", "corrupted", "uncertainty", "locality", "depth")
PROTOCOLS = (*PAPER_PROTOCOLS, "active")  # active: next-best-view (evaluation/active.py), asked for by name
LOSS_NAMES = {"energy_score": "es", "gaussian_nll": "nll", "l2_loss": "l2"}
RESULT_ROW = "eval_row.json"
# The row lists every encoder contributes to an evaluation's result (concatenated over encoders).
ROW_KEYS = ("records", "uncertainty", "error_tracking", "locality", "locality_views", "depth", "active", "rows")
RESULTS = "results.json"
# How a mask input shows in an encoder's name and table label (Table 1: "Ours w/ GT Mask", "Ours w/o Mask").
MASK_VARIANTS = {"gt_mask": ("", "w/ GT Mask"), "none": ("-nomask", "w/o Mask")}


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


@dataclass
class EncoderRun:
    spec: P.EncoderSpec
    predictor: Any
    world: WorldIndex
    reconstructor: Reconstructor
    codes_dir: Path
    keys: list = field(default_factory=list)
    mask_input: str = "gt_mask"
    only: tuple[str, ...] | None = None  # the protocols this variant runs (None: all asked for)


def loss_name(predictor) -> str:
    """es / nll / l2 from the loss `_target_` saved in the checkpoint's hyperparameters."""
    target = str(predictor.model.hparams.loss.get("_target_", ""))
    return LOSS_NAMES.get(target.rsplit(".", 1)[-1], target.rsplit(".", 1)[-1] or "unknown")


def load_encoder(
    run_dir: str | Path,
    settings: Settings,
    cache_dir: Path | None,
    taken: set[str],
    world_dir: str | Path | None = None,
    temperature: bool = False,
    opened: dict[Path, WorldIndex] | None = None,
) -> EncoderRun:
    """A run folder -> its predictor, world (run.json's, or world_dir), decoder and the test views to evaluate.

    temperature=True scales the predicted variances by the temperatures stored beside the checkpoint
    (latent, and SDF where one was fitted).
    The world is checked (and a synthetic one repaired) by `open_world`, once per folder in `opened`.
    """
    from ushape.reconstruction.predictor import load_predictor, read_temperatures

    predictor = load_predictor(run_dir)
    if temperature and predictor.model.predicts_variance:  # FroDO* has no variance to scale
        predictor.temperature, predictor.sdf_temperature = read_temperatures(predictor.checkpoint)
    world_dir = world_dir or predictor.world
    if world_dir is None:
        raise FileNotFoundError(
            f"{run_dir} has no run.json naming its data world (an unfinished run?): "
            "pass the world folder with world=<outputs/data/synthetic/...>"
        )
    opened = {} if opened is None else opened
    key = Path(world_dir).resolve()
    world = opened[key] if key in opened else opened.setdefault(key, open_world(world_dir))
    name = loss_name(predictor)
    if name in taken:  # two runs with one loss: keep both, told apart by their folder
        name = f"{name}:{Path(run_dir).name}"
    taken.add(name)
    spec = P.EncoderSpec(
        name,
        P.encoder_label(name.split(":")[0]) + name[len(name.split(":")[0]) :],
        probabilistic=bool(predictor.model.predicts_variance),
    )
    decoder_dir = decoder_dir_of(predictor)
    tag = f"{decoder_dir.resolve()}|{(decoder_dir / 'decoder.pt').stat().st_mtime_ns}"
    reconstructor = Reconstructor(
        predictor.decoder, tag, world, settings.resolution, cache_dir, n_points=settings.n_points, bf16=settings.bf16
    )
    ids = world.shape_ids(settings.split)[: settings.max_shapes]
    return EncoderRun(spec, predictor, world, reconstructor, decoder_dir, test_views(world, settings.split, ids))


def mask_variants(run: EncoderRun) -> list[EncoderRun]:
    """The run once per mask input its world lists: the first keeps the encoder's name and runs every
    protocol; the others run the single-view protocol under their own name. Labels say which is which
    when there are several."""
    inputs = list(run.world.config.get("mask_inputs", ["gt_mask"]))
    unknown = [m for m in inputs if m not in MASK_INPUTS]
    if unknown or not inputs:
        raise ValueError(f"{run.world.root}: mask_inputs {inputs} must be some of {MASK_INPUTS}")
    if len(inputs) == 1:
        return [replace(run, mask_input=inputs[0])]
    variants = []
    for i, mask_input in enumerate(inputs):
        suffix, label = MASK_VARIANTS[mask_input]
        spec = P.EncoderSpec(
            run.spec.name + ("" if i == 0 else suffix or f"-{mask_input}"),
            f"{run.spec.label} {label}",
            run.spec.probabilistic,
        )
        variants.append(replace(run, spec=spec, mask_input=mask_input, only=None if i == 0 else ("single_view",)))
    return variants


def split_codes(run: EncoderRun, settings: Settings, cache_dir: Path | None) -> CodeTable:
    """The decoder's codes of the evaluated split: stage 1's own, or for shapes the decoder never saw
    (another world), latent-optimised against it (DeepSDF's reconstruction, as stage 1 did for val/test)."""
    table = load_codes(run.codes_dir / codes_file(settings.split))
    ids = run.world.shape_ids(settings.split)
    if set(ids) <= set(table.shape_ids):
        return table
    key = hashlib.sha1(
        f"{run.reconstructor.decoder_tag}|{run.world.root.resolve()}|{settings.split}|"
        f"{settings.code_iterations}".encode()
    ).hexdigest()[:16]
    cache = Path(cache_dir) / f"codes_{key}.pt" if cache_dir is not None else None
    if cache is not None and cache.is_file():
        return load_codes(cache)
    log.info(
        "latent-optimising the codes of %d %s shapes of %s against %s (%d iterations)",
        len(ids),
        settings.split,
        run.world.root,
        run.codes_dir,
        settings.code_iterations,
    )
    shapes = SDFSamplesDataset(run.world.root, settings.split, samples_per_shape=2)  # optimise_codes draws its own
    codes = optimise_codes(
        run.predictor.decoder,
        shapes,
        iterations=settings.code_iterations,
        lr_drop_at=settings.code_iterations // 2,
        seed=settings.seed,
    )
    table = CodeTable(list(shapes.shape_ids), codes.detach().cpu())
    if cache is not None:
        save_codes(cache, table)
    return table


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
