"""The active protocol (`eval.py protocols=[active]`): does letting the uncertainty choose the next view help?

For each held-out shape, each crop setting and each strategy, the loop of `ushape.planning` starts from
the same view (drawn per shape), acquires up to `active_views` views and fuses them (Bayesian); the
fused code after every view is meshed and scored against the ground truth (IoU, Chamfer). A record per
(shape, strategy, min scale, number of views) lands in the evaluation's records with protocol "active",
so Table A, its plot and records.csv all come from them. Acquisitions are cropped like the
corrupted-views protocol (one fixed crop per candidate), so every strategy sees the same image of a view.
"""

from __future__ import annotations

import logging
import math
import zlib
from pathlib import Path
from typing import Sequence

import numpy as np
from tqdm.auto import tqdm

from ushape.decoder.artifacts import CodeTable
from ushape.evaluation.active_cache import load_sequence, sequence_file, store_sequence
from ushape.evaluation.active_diagnostics import RealisedDrops, decision_diagnostics, view_spread
from ushape.evaluation.locality import has_cameras
from ushape.evaluation.plots import save_figure
from ushape.evaluation.tables import Table, encoder_order
from ushape.planning import ViewEncoder, active_reconstruction, build_strategy, candidate_views
from ushape.planning.candidates import SOURCES
from ushape.planning.figures import sequence_figure, step_surfaces
from ushape.planning.information import INFORMATION_STRATEGIES, SeenInformationGain
from ushape.planning.observers import OBSERVERS, FusedGaussian, build_observer
from ushape.planning.strategies import ORACLES, STRATEGIES
from ushape.reconstruction.calibrated_fusion import refinement_prior
from ushape.reconstruction.refine_calibration import seen_model

log = logging.getLogger(__name__)

PROTOCOL = "active"
REFERENCE = "random"


def check_active_settings(settings) -> None:
    """A ValueError that names what is wrong with the active_* settings."""
    known = [*STRATEGIES, *ORACLES]
    unknown = [s for s in settings.active_strategies if s not in known]
    if unknown or settings.active_views < 1 or settings.active_candidates not in SOURCES:
        raise ValueError(
            f"active_strategies must be some of {known}, active_views >= 1 and active_candidates one of {SOURCES}; "
            f"got {list(settings.active_strategies)}, {settings.active_views}, {settings.active_candidates!r}"
        )
    if not all(0 < float(s) <= 1 for s in settings.active_scales):
        raise ValueError(f"active_scales are crop min scales in (0, 1], got {list(settings.active_scales)}")
    if not set(settings.active_observe) <= set(OBSERVERS) or not settings.active_observe:
        raise ValueError(f"active_observe must be some of {list(OBSERVERS)}, got {list(settings.active_observe)}")
    if settings.active_refine_size < 1 or settings.active_refine_iterations < 1:
        raise ValueError(
            "active_refine_size (rays per image side) and active_refine_iterations must be >= 1, got "
            f"{settings.active_refine_size} and {settings.active_refine_iterations}"
        )


def method_name(strategy: str, observe: str) -> str:
    """A row's name in Table A: the strategy, and what the belief was refined on after each view."""
    return strategy if observe == FusedGaussian.name else f"{strategy}+{observe}"


def start_view(seed: int, shape_id: str, n_candidates: int) -> int:
    """The first view of every strategy for one shape: drawn from (seed, shape id) alone."""
    return int(np.random.default_rng([seed, zlib.crc32(shape_id.encode())]).integers(n_candidates))


def shape_candidates(run, settings, shape_id: str):
    return candidate_views(
        run.world, shape_id, settings.active_candidates, settings.active_azimuths, settings.active_elevations
    )


def observer_for(settings, name: str):
    return build_observer(name, size=settings.active_refine_size, iterations=settings.active_refine_iterations)


def sequence(run, settings, candidates, encode, name: str, observer, true_code):
    """One strategy's steps on one shape (from the shared start view), under one observer."""
    options = strategy_options(name, settings.active_refine_size, run.predictor, observer)
    strategy = build_strategy(name, settings.seed, true_code if name in ORACLES else None, **options)
    return active_reconstruction(
        candidates,
        encode,
        strategy,
        run.predictor.decoder,
        settings.active_views,
        start_view(settings.seed, candidates.shape_id, len(candidates)),
        fusion=loop_fusion(run.predictor, observer),
        resolution=settings.resolution,
        observe=observer,
    )


def loop_fusion(predictor, observer):
    """The rule that fuses the views taken: Bayesian (the paper's) for the fused belief; for a refining
    observer, the prior reconstruct.py refines, the run's calibrated `shared` rule where fitted (Bayesian's
    variance shrinks as 1/V while the views' shared error stays, so a refinement from it is held near the
    fused mean: measured, the refined IoU fell when a view was added in 40-60 % of the steps)."""
    if getattr(observer, "name", FusedGaussian.name) == FusedGaussian.name:
        return None
    return refinement_prior(predictor)


def strategy_options(name: str, size: int, predictor, observer) -> dict:
    """The information strategies' rays per side (`size`); information-seen's floors, the predictor's run's seen
    model fitted for what the loop observes (masks where it observes nothing); an oracle's observer (it scores the
    belief the loop would hold: the fused code, or its refinement)."""
    if name in ORACLES:
        return {"observer": observer}
    if name not in INFORMATION_STRATEGIES:
        return {}
    options = {"size": size}
    if name == SeenInformationGain.name:
        options["floors"] = seen_model(predictor.checkpoint, getattr(observer, "name", FusedGaussian.name))
    return options


def active_records(run, settings, codes: CodeTable, cache_dir: Path | None = None) -> tuple[list[dict], list[dict]]:
    """Records: one per (shape, min scale, strategy and observer, views 1..N), the belief after that many views,
    scored. Diagnostics: one per sequence, its views' spread and what its decisions were based on (Table A-why).
    Each finished sequence is kept under cache_dir and read back on a later run (`evaluation.active_cache`)."""
    if not run.spec.probabilistic:
        log.info("active protocol skipped for %s: it predicts no variance to plan with", run.spec.label)
        return [], []
    shape_ids = list(dict.fromkeys(k.shape_id for k in run.keys))[: settings.active_shapes]
    if not has_cameras(run.world, shape_ids):
        log.warning(
            "Table A skipped: the views of %s have no cameras (views.npz), so no candidate pose can be "
            "scored (real photos: a world built with the photos' cameras would do)",
            run.world.root,
        )
        return [], []
    records, diagnostics = [], []
    for shape_id in tqdm(shape_ids, desc=f"{run.spec.name} active", leave=False):
        candidates = shape_candidates(run, settings, shape_id)
        true_code = codes.lookup(shape_id)
        for scale in settings.active_scales:
            encode = ViewEncoder(run.predictor, candidates, scale, settings.seed)
            for observe in observable(settings.active_observe, candidates):
                for name in settings.active_strategies:
                    row = {"encoder": run.spec.name, "label": run.spec.label, "min_scale": float(scale)}
                    row["method"] = method_name(name, observe)
                    cache = sequence_file(cache_dir, run, settings, shape_id, true_code, scale, observe, name)
                    kept = load_sequence(cache)
                    if kept is None:
                        kept = run_sequence(run, settings, candidates, encode, name, observe, true_code)
                        store_sequence(cache, **kept)
                    records += [{**row, **step} for step in kept["steps"]]
                    diagnostics.append(
                        {**row, "shape_id": shape_id, "spread": kept["spread"], "decisions": kept["decisions"]}
                    )
    return records, diagnostics


def run_sequence(run, settings, candidates, encode, name: str, observe: str, true_code) -> dict:
    """One sequence run and scored: {"steps": a record per step (without the row's names), "spread": the views'
    spread, "decisions": Table A-why's rows}."""
    observer = observer_for(settings, observe)
    steps = sequence(run, settings, candidates, encode, name, observer, true_code)
    drops = RealisedDrops(encode, true_code, run.predictor.decoder, observer)
    return {
        "steps": step_records(run, candidates.shape_id, steps),
        "spread": view_spread(steps, candidates),
        "decisions": decision_diagnostics(steps, drops, run.predictor.decoder, name in INFORMATION_STRATEGIES),
    }


def observable(names, candidates) -> list[str]:
    """The observers that can run on these candidates: refining needs their masks (a world's views.npz without
    masks has none); the others are skipped with a warning."""
    if candidates.observation is not None:
        return list(names)
    skipped = [n for n in names if n != FusedGaussian.name]
    if skipped:
        log.warning(
            "active_observe %s skipped for %s: its views have no masks to refine on", skipped, candidates.shape_id
        )
    return [n for n in names if n == FusedGaussian.name]


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


def save_active_sequence(run, settings, out_dir: Path, strategy: str = "uncertainty") -> list[Path]:
    """The first shape's sequence under `strategy`, clean and at each crop: plots/active_sequence_*.png."""
    if not run.spec.probabilistic or strategy not in settings.active_strategies:
        return []
    if not has_cameras(run.world, [run.keys[0].shape_id]):
        return []
    shape_id = run.keys[0].shape_id
    candidates = shape_candidates(run, settings, shape_id)
    start = start_view(settings.seed, shape_id, len(candidates))
    written = []
    for scale in settings.active_scales:
        encode = ViewEncoder(run.predictor, candidates, scale, settings.seed)
        steps = active_reconstruction(
            candidates,
            encode,
            build_strategy(strategy, settings.seed),
            run.predictor.decoder,
            settings.active_views,
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


# metric -> (its name in the tables, +1 where higher is better, -1 where lower is)
METRICS = {"iou": ("IoU", 1), "cd": ("CD", -1)}


def curves(records: Sequence[dict], metric: str = "iou") -> dict[tuple, dict[int, list[float]]]:
    """(encoder, min scale, strategy) -> views -> the metric per shape, in shape order (NaN: empty mesh)."""
    out: dict[tuple, dict[int, list[float]]] = {}
    for r in records:
        if r["protocol"] == PROTOCOL:
            value = r.get(metric)
            value = math.nan if value is None else float(value)
            out.setdefault((r["encoder"], r["min_scale"], r["method"]), {}).setdefault(r["views"], []).append(value)
    return out


def views_to_reach(means: dict[int, float], target: float, sign: int = 1) -> int | None:
    """The fewest views whose mean reaches target (sign -1: at or below it); None: none does."""
    return next((k for k in sorted(means) if sign * means[k] >= sign * target - 1e-12), None)


def standard_error(values: Sequence[float]) -> float:
    """Standard error of the mean of the finite values (0 for fewer than two)."""
    values = np.asarray(values, np.float64)
    values = values[np.isfinite(values)]
    return float(np.std(values, ddof=1) / math.sqrt(len(values))) if len(values) > 1 else 0.0


def paired_gain(curve: dict[int, list[float]], reference: dict[int, list[float]], sign: int = 1) -> tuple[float, float]:
    """Mean per-shape improvement over the reference across views 2..N (sign -1: a drop is the improvement),
    and its standard error over shapes; shapes with an empty mesh at some view average the other views."""
    views = [k for k in sorted(curve) if k > 1 and k in reference]
    if not views:
        return math.nan, math.nan
    with np.errstate(invalid="ignore"):
        per_view = sign * np.subtract([curve[k] for k in views], [reference[k] for k in views])  # [views, shapes]
        finite = np.isfinite(per_view).any(axis=0)
        if not finite.any():
            return math.nan, math.nan
        gains = np.nanmean(per_view[:, finite], axis=0)
    return float(gains.mean()), standard_error(gains) if len(gains) > 1 else math.nan


def step_seconds(curve: dict[int, list[float]]) -> float | None:
    """Mean wall time of a step after the first (choosing the view and forming the belief after it)."""
    values = [v for k, vs in curve.items() if k > 1 for v in vs if math.isfinite(v)]
    return float(np.mean(values)) if values else None


def reference_of(method: str) -> str:
    """The row a method is compared with: random under the same observer (its belief refined alike)."""
    _, plus, observe = method.partition("+")
    return REFERENCE + plus + observe


def table_active(records: Sequence[dict], metric: str = "iou") -> Table:
    """Table A: the metric after 1..N views per strategy (mean over shapes; sd at N), and against random."""
    name, sign = METRICS[metric]
    data = curves(records, metric)
    n = max((max(c) for c in data.values()), default=0)
    reach = n - 1 if n > 2 else n
    table = Table(
        f"Table A: active reconstruction ({name} after k views)",
        "Each held-out shape starts from the same view for every strategy; views fused by the Bayesian rule "
        "(refined rows: the run's calibrated shared rule where fitted, the prior reconstruct.py refines). "
        f"'gain vs random': mean per-shape {name} {'gain' if sign > 0 else 'drop'} against random over views "
        f"2-{n}, +- its standard error over shapes (positive: better than random). 'views to reach': the fewest "
        f"views whose mean {name} reaches random's at {reach} views. The oracles look at the answer (oracle: "
        "the belief's distance from the shape's own code; oracle-occupancy: its shape's): no robot could run them. "
        "'strategy+masks' / '+depth': the belief after each view is the fused Gaussian refined on every view taken "
        "(compared with random+masks / +depth). 's / step': mean seconds of a step after the first (scoring the "
        "candidates, then fusing and refining).",
        ["Encoder", "min scale", "strategy", *[f"{name} {k}" for k in range(1, n + 1)], f"sd {n}", "shapes"]
        + ["gain vs random", "s.e.", f"views to reach random@{reach}", "s / step"],
    )
    timing = curves(records, "seconds")
    labels = dict(encoder_order([{"encoder": r["encoder"], "label": r["label"]} for r in records]))
    for (encoder, scale, method), curve in sorted(data.items(), key=lambda item: (item[0][0], -item[0][1])):
        means = {k: float(np.nanmean(v)) for k, v in curve.items()}
        baseline = reference_of(method)
        reference = data.get((encoder, scale, baseline), {})
        gain, se = paired_gain(curve, reference, sign) if method != baseline else (math.nan, math.nan)
        target = float(np.nanmean(reference[reach])) if reach in reference else None
        last = np.asarray(curve.get(n, []), np.float64)
        table.rows.append(
            [labels.get(encoder, encoder), scale, method, *[means.get(k) for k in range(1, n + 1)]]
            + [float(np.nanstd(last, ddof=1)) if np.isfinite(last).sum() > 1 else None, len(curve.get(1, []))]
            + [gain, se, None if target is None else (views_to_reach(means, target, sign) or f"> {n}")]
            + [step_seconds(timing.get((encoder, scale, method), {}))]
        )
    return table


def plot_active(records: Sequence[dict]):
    """IoU (top) and Chamfer (bottom) against views taken, a column per crop setting, a line per strategy
    with a +-1 standard-error band over shapes."""
    from matplotlib.figure import Figure

    scales = sorted({key[1] for key in curves(records)}, reverse=True)
    fig = Figure(figsize=(4.6 * max(len(scales), 1), 6.6))
    axes = fig.subplots(len(METRICS), max(len(scales), 1), squeeze=False)
    for row, (metric, (name, _)) in enumerate(METRICS.items()):
        data = curves(records, metric)
        for ax, scale in zip(axes[row], scales):
            for (encoder, s, method), curve in sorted(data.items()):
                if s != scale:
                    continue
                views = sorted(curve)
                mean = np.array([np.nanmean(curve[k]) for k in views])
                se = np.array([standard_error(curve[k]) for k in views])
                style = {"linestyle": ":"} if method.partition("+")[0] in ORACLES else {}
                (line,) = ax.plot(views, mean, marker="o", label=f"{encoder} {method}", **style)
                ax.fill_between(views, mean - se, mean + se, color=line.get_color(), alpha=0.15)
            ax.set(xlabel="views taken", ylabel=name, title=f"{name}, crops of area [{scale:g}, 1]")
            ax.legend(fontsize="x-small")
    fig.tight_layout()
    return fig
