"""The active protocol (`eval.py protocols=[active]`): does letting the uncertainty choose the next view help?

For each held-out shape, each crop setting and each strategy, the loop of `ushape.planning` starts from
the same view (drawn per shape), acquires up to the plan's `views` views and fuses them (Bayesian); the
fused code after every view is meshed and scored against the ground truth (IoU, Chamfer). A record per
(shape, strategy, min scale, number of views) lands in the evaluation's records with protocol "active",
so Table A, its plot and records.csv all come from them. Acquisitions are cropped like the
corrupted-views protocol (one fixed crop per candidate), so every strategy sees the same image of a view.
"""

from __future__ import annotations

import logging
from pathlib import Path

from tqdm.auto import tqdm

from ushape.decoder.artifacts import CodeTable
from ushape.evaluation.active_cache import load_sequence, sequence_file, store_sequence
from ushape.evaluation.active_diagnostics import RealisedDrops, decision_diagnostics, view_spread
from ushape.evaluation.active_tables import PROTOCOL
from ushape.evaluation.locality import has_cameras
from ushape.evaluation.plots import save_figure
from ushape.planning import SequenceContext, ViewEncoder, active_reconstruction, build_strategy
from ushape.planning.figures import sequence_figure, step_surfaces
from ushape.planning.plugins import predicts_rows
from ushape.planning.sequence import (
    ActivePlan,
    method_name,
    observable,
    observer_for,
    run_strategy,
    shape_candidates,
    start_view,
)

log = logging.getLogger(__name__)


def active_records(
    run, settings, plan: ActivePlan, codes: CodeTable, cache_dir: Path | None = None
) -> tuple[list[dict], list[dict]]:
    """Records: one per (shape, min scale, strategy and observer, views 1..N), the belief after that many views,
    scored. Diagnostics: one per sequence, its views' spread and what its decisions were based on (Table A-why).
    Each finished sequence is kept under cache_dir and read back on a later run (`evaluation.active_cache`)."""
    if not run.spec.probabilistic:
        log.info("active protocol skipped for %s: it predicts no variance to plan with", run.spec.label)
        return [], []
    shape_ids = list(dict.fromkeys(k.shape_id for k in run.keys))[: plan.shapes]
    if not has_cameras(run.world, shape_ids):
        log.warning(
            "Table A skipped: the views of %s have no cameras (views.npz), so no candidate pose can be "
            "scored (real photos: a world built with the photos' cameras would do)",
            run.world.root,
        )
        return [], []
    records, diagnostics = [], []
    for shape_id in tqdm(shape_ids, desc=f"{run.spec.name} active", leave=False):
        candidates = shape_candidates(run.world, shape_id, plan)
        true_code = codes.lookup(shape_id)
        for scale in plan.scales:
            encode = ViewEncoder(run.predictor, candidates, scale, settings.seed)
            for observe in observable(plan.observe, candidates):
                for name in plan.strategies:
                    row = {"encoder": run.spec.name, "label": run.spec.label, "min_scale": float(scale)}
                    row["method"] = method_name(name, observe)
                    cache = sequence_file(cache_dir, run, settings, plan, shape_id, true_code, scale, observe, name)
                    kept = load_sequence(cache)
                    if kept is None:
                        kept = run_sequence(run, settings, plan, candidates, encode, name, observe, true_code)
                        store_sequence(cache, **kept)
                    records += [{**row, **step} for step in kept["steps"]]
                    diagnostics.append(
                        {**row, "shape_id": shape_id, "spread": kept["spread"], "decisions": kept["decisions"]}
                    )
    return records, diagnostics


def run_sequence(run, settings, plan: ActivePlan, candidates, encode, name: str, observe: str, true_code) -> dict:
    """One sequence run and scored: {"steps": a record per step (without the row's names), "spread": the views'
    spread, "decisions": Table A-why's rows}."""
    observer = observer_for(plan, observe)
    steps = run_strategy(
        run.predictor, plan, settings.seed, settings.resolution, candidates, encode, name, observer, true_code
    )
    drops = RealisedDrops(encode, true_code, run.predictor.decoder, observer)
    return {
        "steps": step_records(run, candidates.shape_id, steps),
        "spread": view_spread(steps, candidates),
        "decisions": decision_diagnostics(steps, drops, run.predictor.decoder, predicts_rows(name, plan.strategy_dirs)),
    }


def step_records(run, shape_id: str, steps) -> list[dict]:
    """A record per step: the belief's code after k views scored against the shape, with the step's seconds."""
    records = []
    for k, step in enumerate(steps, start=1):
        scores = run.reconstructor.scores(step.mu, shape_id)
        views = "-".join(str(s.view) for s in steps[:k])
        records.append(
            {"protocol": PROTOCOL, "views": k, "shape_id": shape_id, "item": views}
            | {"iou": scores["iou"], "cd": scores["cd"], "seconds": step.seconds, "fallback": step.fallback or ""}
        )
    return records


def save_active_sequence(run, settings, plan: ActivePlan, out_dir: Path, strategy: str = "uncertainty") -> list[Path]:
    """The first shape's sequence under `strategy`, clean and at each crop: plots/active_sequence_*.png."""
    if not run.spec.probabilistic or strategy not in plan.strategies:
        return []
    if not has_cameras(run.world, [run.keys[0].shape_id]):
        return []
    shape_id = run.keys[0].shape_id
    candidates = shape_candidates(run.world, shape_id, plan)
    start = start_view(settings.seed, shape_id, len(candidates))
    written = []
    for scale in plan.scales:
        encode = ViewEncoder(run.predictor, candidates, scale, settings.seed)
        steps = active_reconstruction(
            candidates,
            encode,
            build_strategy(strategy, SequenceContext(seed=settings.seed), plan.strategy_dirs),
            run.predictor.decoder,
            plan.views,
            start,
            resolution=settings.resolution,
        )
        fig = sequence_figure(
            [encode.input(s.view) for s in steps],
            steps,
            step_surfaces(steps, run.predictor.decoder, candidates, settings.resolution),
            candidates,
            [run.reconstructor.scores(step.mu, shape_id)["iou"] for step in steps],
            f"{run.spec.label}, {strategy} strategy, {shape_id}, crops of area [{scale:g}, 1]",
        )
        written.append(save_figure(fig, out_dir / "plots" / f"active_sequence_{run.spec.name}_{scale:g}.png"))
    return written
