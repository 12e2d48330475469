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
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Sequence

from ushape.data.layout import WorldIndex
from ushape.decoder.precision import resolve_precision
from ushape.evaluation import protocols as P
from ushape.evaluation.context import EvalContext
from ushape.evaluation.encoders import EncoderRun, load_encoder, mask_variants
from ushape.evaluation.methods import ReconstructionMethod, fallback_lines, method_variants
from ushape.evaluation.plugin import Protocol
from ushape.evaluation.settings import Settings
from ushape.evaluation.showcase import Showcase, save_showcase
from ushape.evaluation.views import encode_views
from ushape.workspace import RESULTS

log = logging.getLogger(__name__)


def evaluate_encoder(
    run: EncoderRun,
    settings: Settings,
    cache_dir: Path | None,
    setting: tuple[Callable, str, float] | None = None,
    protocols: Sequence[Protocol] = (),
) -> dict[str, list]:
    """Records of every protocol asked for, their row lists and curves, and the configured setting's row."""
    asked = {p.name: p for p in protocols if run.only is None or p.name in run.only}
    context = EvalContext(run, settings, cache_dir, asked)
    outputs = [context.output(name) for name in asked]
    out: dict[str, Any] = {"records": [], "rows": [], "curves": {}}
    out["records"] = context.records() + [record for output in outputs for record in output.records]
    for output in outputs:
        for key, rows in output.rows.items():
            out[key] = out.get(key, []) + rows
        out["curves"].update(output.curves)
    if setting is not None and run.only is None:
        out["rows"].append(setting_row(context, *setting))
    return out


def setting_row(context: EvalContext, fuse: Callable, method: str, min_scale: float) -> dict:
    """One sweep row: single-view and fused multi-view IoU at the configured fusion rule and crop."""
    run, settings, groups = context.run, context.settings, context.groups
    views = context.views(min_scale, settings.single_view_views)
    single = P.summarise(P.single_view_records(run.spec, views, run.reconstructor, min_scale))[0]
    after = context.after_fusion(min_scale)
    fused = P.multi_view_records(
        run.spec, context.encode(min_scale), groups, {method: fuse}, run.reconstructor, min_scale, False, after
    )
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
    protocols: Sequence[Protocol] = (),
    methods: Sequence[ReconstructionMethod] = (),
    showcase: Showcase = Showcase(),
) -> dict[str, Any]:
    """Load every run folder's encoder and evaluate them all (see `evaluate_all`)."""
    if not run_dirs:
        raise ValueError("no runs to evaluate: pass runs=[<run folder>, ...] or sweep=<multirun folder>")
    requested = settings.precision
    resolved, why = resolve_precision(requested)  # the decoders are loaded onto the CPU
    settings = replace(settings, precision=resolved)
    taken: set[str] = set()
    opened: dict[Path, WorldIndex] = {}
    runs = [load_encoder(run_dir, settings, cache_dir, taken, world_dir, temperature, opened) for run_dir in run_dirs]
    variants = [(variant, run_dir) for run, run_dir in zip(runs, run_dirs) for variant in mask_variants(run)]
    result = evaluate_all(
        [v for v, _ in variants], settings, cache_dir, setting, showcase_dir, protocols, methods, showcase
    )
    for run, run_dir in variants:
        for method in [None, *methods]:
            name = run.spec.name if method is None else f"{run.spec.name}+{method.name}"
            result["runs"][name]["run_dir"] = str(run_dir)
    result["precision"] = {"requested": requested, "resolved": resolved, "why": why}
    return result


def evaluate_all(
    runs: Sequence[EncoderRun],
    settings: Settings,
    cache_dir: Path | None = None,
    setting: tuple[Callable, str, float] | None = None,
    showcase_dir: Path | None = None,
    protocols: Sequence[Protocol] = (),
    methods: Sequence[ReconstructionMethod] = (),
    showcase: Showcase = Showcase(),
) -> dict[str, Any]:
    """Every protocol for every encoder -> {records, rows, each protocol's row lists, curves, runs, summary,
    settings, protocols, seconds}.

    protocols: the built protocol objects (evaluation.plugin.load_protocols), run in this order. With
    showcase_dir, the first shapes' reconstructions with uncertainty are saved there (see showcase), and
    each protocol's figures. methods: reconstruction methods each encoder is scored with too, as rows of
    their own (see methods).
    """
    started = time.time()
    runs = [variant for run in runs for variant in method_variants(run, methods)]
    result: dict[str, Any] = {"records": [], "rows": [], "curves": {}, "runs": {}}
    for run in runs:
        log.info("evaluating %s on %d views of %s", run.spec.label, len(run.keys), run.world.root)
        part = evaluate_encoder(run, settings, cache_dir, setting, protocols)
        for key, rows in part.items():
            if key != "curves":
                result[key] = result.get(key, []) + rows
        for space, curves in part["curves"].items():
            result["curves"].setdefault(space, {}).update(curves)
        result["runs"][run.spec.name] = {
            "checkpoint": str(run.predictor.checkpoint),
            "world": str(run.world.root),
            "label": run.spec.label,
        }
        if showcase_dir is not None and run.only is None and run.method is None:
            save_figures(run, settings, cache_dir, showcase_dir, protocols, showcase)
    for protocol in protocols:
        result["records"] += protocol.after_all(runs, settings, cache_dir)
    result["summary"] = P.summarise(result["records"])
    for line in fallback_lines(result["summary"]):
        log.info(line)
    result["settings"] = {k: (list(v) if isinstance(v, (tuple, range)) else v) for k, v in vars(settings).items()}
    result["protocols"] = {protocol.name: protocol.config() for protocol in protocols}
    result["seconds"] = round(time.time() - started, 1)
    return result


def save_figures(
    run: EncoderRun, settings: Settings, cache_dir: Path | None, out_dir: Path, protocols, showcase: Showcase
) -> None:
    """The showcase meshes of one encoder (see showcase) and every protocol's figures, under out_dir."""
    if showcase.shapes > 0:
        encodings = encode_views(
            run.predictor, run.world, run.keys, 1.0, settings.seed, cache_dir, mask_input=run.mask_input
        )
        save_showcase(
            run,
            encodings,
            out_dir,
            settings.group_size,
            showcase.shapes,
            settings.resolution,
            showcase.mc_samples,
            seed=settings.seed,
        )
    for protocol in protocols:
        protocol.save_figures(run, settings, out_dir)


def load_results(path: str | Path) -> dict[str, Any]:
    """An evaluation's results.json (a folder holding one, or the file)."""
    path = Path(path)
    path = path / RESULTS if path.is_dir() else path
    if not path.is_file():
        raise FileNotFoundError(f"no {RESULTS} at {path}: run `python eval.py` first")
    return json.loads(path.read_text())
