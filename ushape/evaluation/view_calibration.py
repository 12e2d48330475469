"""Calibration across views: is a fused code's variance honest at 1, 3 and 10 fused views, per fusion rule?

For each held-out shape with V views, `draws` subsets of n distinct views (n = 1: every view) are fused
with each rule and scored against the shape's own code, per latent dimension (and, propagated through
the decoder, per ground-truth SDF sample): the calibration error (area between the calibration curve
and Y = X, supplement S2.2), the mean squared error over the mean variance ("error / trace": 1 when
calibrated), and the coverage of the 90 % interval. Bayesian fusion treats the views as independent;
their errors are mostly shared, so its variance shrinks with n far faster than its error.

A reconstruction method's step after fusion (a refinement on the fused views) is applied to every fused
subset: its full covariance goes into the SDF propagation as it is; the latent scores, per dimension,
read its diagonal (each dimension's marginal, exact for them).
"""

from __future__ import annotations

from functools import partial
from typing import Callable, Mapping, Sequence

import torch
from torch import Tensor

from ushape.evaluation.methods import log_fallbacks, stack_variances
from ushape.evaluation.views import Estimate
from ushape.fusion.rules import FusedCode
from ushape.fusion.subsets import view_subsets
from ushape.metrics.calibration import (
    calibration_curve,
    calibration_error,
    calibration_error_interval,
    two_sided_quantile,
)
from ushape.propagation import clamped_sdf_errors

FusionRule = Callable[[Tensor, Tensor], FusedCode]  # (mu [V, D], var [V, D]) -> fused Gaussian
# A method's step after fusion for one shape: (fused Gaussian, the shape's view indices fused) -> the one scored.
AfterSubset = Callable[[Estimate, list[int]], Estimate]
VIEW_COUNTS = (1, 3, 10)
COVERAGE = 0.9


def interval_scores(abs_error: Tensor, std: Tensor, n_levels: int = 20) -> dict[str, float]:
    """Calibration error, mean squared error / mean variance, and 90 % coverage of |error| [N] against std [N]."""
    abs_error, std = abs_error.reshape(-1).double(), std.reshape(-1).double()
    p, freq = calibration_curve(abs_error, std, n_levels)
    inside = abs_error <= float(two_sided_quantile(torch.tensor(COVERAGE, dtype=torch.float64))) * std
    return {
        "calibration_error": calibration_error(p, freq),
        "error_over_var": float(abs_error.square().mean() / std.square().mean().clamp(min=1e-30)),
        "coverage90": float(inside.double().mean()),
    }


def fused_errors(
    rule: FusionRule,
    mu: Tensor,  # [V, D]
    var: Tensor,  # [V, D]
    code: Tensor,  # [D]
    subsets: Tensor,  # [R, n]
    after: AfterSubset | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """(fused mu [R, D], fused var [R, D] (or [R, D, D] after a method's step), |fused mu - code| [R, D]) of
    one shape's view subsets, fused as one batch [R, n, D] (every rule of ushape.fusion takes a batch),
    then each passed through `after` where given."""
    fused = rule(mu[subsets], var[subsets])
    if after is None:
        return fused.mu, fused.var, (fused.mu - code).abs()
    steps = [after(Estimate(m, v), row.tolist()) for m, v, row in zip(fused.mu, fused.var, subsets)]
    fused_mu = torch.stack([step.mu for step in steps])
    return fused_mu, stack_variances([step.var for step in steps]), (fused_mu - code).abs()


def marginal(var: Tensor) -> Tensor:  # [R, D] or [R, D, D] -> [R, D]
    """Each dimension's own variance: a diagonal as it is, a full covariance's diagonal."""
    return var if var.ndim == 2 else torch.diagonal(var, dim1=-2, dim2=-1)


def rule_sdf_temperature(
    rule: FusionRule, sdf_temperature: float | None, after=None, after_sdf: tuple | None = None
) -> tuple[float | None, float | None, float | None]:
    """(SDF temperature, SDF floor, SDF distance scale) a rule's fused variance gets: after a method's step, the
    method's (temperature, floor) where fitted (`after_sdf`), else the run's single-view temperature alone; with
    no step, the rule's own where it carries them (`shared`, fitted on its fused val variance), else the same."""
    if after is not None:
        return (*after_sdf, None) if after_sdf is not None else (sdf_temperature, None, None)
    own = getattr(rule, "sdf_temperature", None)
    if own is None:
        return sdf_temperature, None, None
    return own, getattr(rule, "sdf_floor", None), getattr(rule, "sdf_distance_scale", None)


def calibration_across_views(
    rules: Mapping[str, FusionRule],
    views: Sequence[tuple[Tensor, Tensor, Tensor]],  # per shape: (mu [V, D], var [V, D], code [D])
    view_counts: Sequence[int] = VIEW_COUNTS,
    draws: int = 12,
    seed: int = 0,
    sdf: Sequence[tuple[Tensor, Tensor]] | None = None,  # per shape: (points [P, 3], sdf [P])
    decoder=None,
    sdf_temperature: float | None = None,
    after: Sequence[AfterSubset] | None = None,  # per shape: a method's step after fusion
    after_sdf: Callable[[int], tuple[float, float | None] | None] | None = None,  # n -> the step's (T_sdf, floor)
) -> list[dict]:
    """One row per (rule, n views): latent (and with `sdf`, SDF) calibration scores over every shape.

    sdf_temperature scales every rule's propagated SDF variance, except a rule's that carries its own and,
    after a method's step, the method's own `after_sdf` where given (`rule_sdf_temperature`).

    Every rule fuses the same subsets of views. A shape with fewer than n views is left out of that n's
    rows; `n_shapes` says how many were scored.
    """
    rows = []
    for n in view_counts:
        generator = torch.Generator().manual_seed(seed + n)
        usable = [i for i, (mu, _, _) in enumerate(views) if mu.shape[0] >= n]
        subsets = {i: view_subsets(views[i][0].shape[0], n, draws, generator) for i in usable}
        for name, rule in rules.items():
            latent_err, latent_std, sdf_err, sdf_std = [], [], [], []
            for i in usable:
                mu, var, code = views[i]
                step = None if after is None else after[i]
                fused_mu, fused_var, error = fused_errors(rule, mu, var, code, subsets[i], step)
                latent_err.append(error.reshape(-1)), latent_std.append(marginal(fused_var).sqrt().reshape(-1))
                if sdf is not None:
                    own = None if after_sdf is None else after_sdf(n)
                    calibration = rule_sdf_temperature(rule, sdf_temperature, after, own)
                    e, s = clamped_sdf_errors(decoder, fused_mu, fused_var, *sdf[i], *calibration)
                    sdf_err.append(e.reshape(-1)), sdf_std.append(s.reshape(-1))
            if not usable:
                continue
            row = {"fusion": name, "n_views": n, "n_shapes": len(usable)}
            row.update(
                {f"latent_{k}": v for k, v in interval_scores(torch.cat(latent_err), torch.cat(latent_std)).items()}
            )
            row["latent_calibration_error_90"] = calibration_error_interval(latent_err, latent_std, seed=seed + n)
            if sdf is not None:
                row.update({f"sdf_{k}": v for k, v in interval_scores(torch.cat(sdf_err), torch.cat(sdf_std)).items()})
                row["sdf_calibration_error_90"] = calibration_error_interval(sdf_err, sdf_std, seed=seed + n)
            rows.append(row)
    return rows


def plot_calibration_across_views(rows: Sequence[dict], target: float = 0.05):
    """A Figure: calibration error against views fused, one line per rule (per row label and rule where rows of
    several labels are given); latent and (if scored) SDF panels."""
    from matplotlib.figure import Figure

    if not rows:
        raise ValueError("no rows to plot: run calibration_across_views first")
    spaces = [s for s in ("latent", "sdf") if f"{s}_calibration_error" in rows[0]]
    fig = Figure(figsize=(4.2 * len(spaces), 3.6))
    for j, space in enumerate(spaces):
        ax = fig.add_subplot(1, len(spaces), j + 1)
        several = len({r.get("label") for r in rows}) > 1  # an encoder and its methods: one line each
        for label, name in dict.fromkeys((r.get("label"), r["fusion"]) for r in rows):
            mine = [r for r in rows if (r.get("label"), r["fusion"]) == (label, name)]
            ax.plot(
                [r["n_views"] for r in mine],
                [r[f"{space}_calibration_error"] for r in mine],
                marker="o",
                label=f"{label}: {name}" if several else name,
            )
        ax.axhline(target, linestyle="--", color="black", linewidth=1, label=f"target {target}")
        ax.set(xlabel="views fused", ylabel="calibration error", title=f"{space} calibration across views")
        ax.set_xscale("log")
        ax.legend(fontsize="small")
    fig.tight_layout()
    return fig


def evaluation_rules(checkpoint, k: int) -> tuple[dict[str, FusionRule], float | None, float | None]:
    """(every fusion rule by name, latent T, SDF T) for a run: the paper's three, intersection, and `shared`
    (with `shared`-K, each carrying its own SDF temperature) where --fit-temperature stored the shared error;
    without it, a warning says how."""
    import logging

    from ushape.fusion import (
        AverageFusion,
        BayesianFusion,
        BayesianKFusion,
        CovarianceIntersectionFusion,
        SharedErrorFusion,
    )
    from ushape.reconstruction.calibrated_fusion import with_fit
    from ushape.reconstruction.predictor import read_shared_error, read_temperatures, temperature_path

    rules = {"average": AverageFusion(), "bayesian": BayesianFusion(), f"bayesian-{k}": BayesianKFusion(k)}
    rules["intersection"] = CovarianceIntersectionFusion()
    fit = read_shared_error(checkpoint)
    if fit is None:
        logging.getLogger(__name__).warning(
            "calibration across views without the shared rule: %s has no shared error; fit it with "
            "`python reconstruct.py --fit-temperature --checkpoint %s`",
            temperature_path(checkpoint),
            checkpoint,
        )
        return rules, None, None
    rules["shared"] = with_fit(SharedErrorFusion(), fit, checkpoint)
    rules[f"shared-{k}"] = with_fit(SharedErrorFusion(k=k), fit, checkpoint)
    return rules, *read_temperatures(checkpoint)


def calibrated_rule(run) -> dict[str, FusionRule]:
    """{"shared": the run's calibrated rule} where `--fit-temperature` stored its shared error, else {}.

    The shared error was fitted on temperature-scaled view variances, so the rule scales them by the stored
    latent T where the evaluation did not apply it already. Its mean is Bayesian's, so its plain rows repeat
    Bayesian's IoU; a refinement takes its (wider) variance as the prior, as `reconstruct.py --refine` does.
    """
    from ushape.reconstruction.calibrated_fusion import refinement_prior

    rule = refinement_prior(run.predictor) if run.spec.probabilistic else None
    return {} if rule is None else {"shared": rule}


def view_calibration_protocol(
    run, seed: int, encodings, codes, draws: int = 6, k: int = 4, n_sdf: int = 1024, after=None
) -> list[dict]:
    """Table V's rows for one evaluated run: every rule at 1, 3 and 10 fused test views, latent and SDF.

    All rules fuse the temperature-scaled view variances (the shared error was fitted on them): the
    stored T is applied here where the evaluation did not apply it already. after: a method's step after
    fusion, (fused Gaussian, view keys) -> the Gaussian scored (None: the fused one). k: Bayesian-K's K;
    n_sdf: ground-truth SDF samples per shape.
    """
    from ushape.data.sdf_dataset import sdf_points

    if not run.spec.probabilistic:
        return []
    rules, latent_t, sdf_t = evaluation_rules(run.predictor.checkpoint, k)
    scale = latent_t if latent_t is not None and run.predictor.temperature is None else 1.0
    sdf_t = run.predictor.sdf_temperature if run.predictor.sdf_temperature is not None else sdf_t
    ids = list(dict.fromkeys(key.shape_id for key in encodings.keys))
    fallbacks: list[str | None] = []

    def counted(fused, keys):
        estimate = after(fused, keys)
        fallbacks.append(estimate.fallback)
        return estimate

    views, sdf, steps = [], [], []
    for shape_id in ids:
        rows = [i for i, key in enumerate(encodings.keys) if key.shape_id == shape_id]
        views.append((encodings.mu[rows], encodings.var[rows] * scale, codes.lookup(shape_id)))
        sdf.append(sdf_points(run.world, shape_id, n_sdf))
        keys = [encodings.keys[i] for i in rows]
        steps.append(lambda fused, subset, keys=keys: counted(fused, [keys[j] for j in subset]))
    decoder = run.predictor.decoder
    rows = calibration_across_views(
        rules,
        views,
        draws=draws,
        seed=seed,
        sdf=sdf,
        decoder=decoder,
        sdf_temperature=sdf_t,
        after=None if after is None else steps,
        after_sdf=None if after is None or run.method is None else partial(run.method.sdf_calibration_for, run),
    )
    log_fallbacks(run.spec.name, fallbacks, "Table V fused view subsets")
    return [{"encoder": run.spec.name, "label": run.spec.label, **row} for row in rows]


def span(interval: Sequence[float] | None) -> str:
    """'0.031-0.072': an interval as a table cell ('-' where none was computed)."""
    return "-" if interval is None else f"{interval[0]:.3f}-{interval[1]:.3f}"


def table_view_calibration(rows: Sequence[dict]):
    """Table V: calibration across views, per encoder, fusion rule and number of fused views."""
    from ushape.evaluation.tables import Table

    table = Table(
        "Table V: calibration across fused views",
        "Each test shape's views fused n at a time (n = 1: every view; else random subsets of n distinct views) "
        "by each rule, on temperature-scaled view variances, against the shape's own code (latent, per "
        "dimension) and its ground-truth SDF samples (linearised propagation, SDF temperature applied: the "
        "shared rule's own, fitted on its fused val variance, the single-view one for the others). CE: "
        "calibration error; err/var: mean squared error over mean variance (1 when calibrated); cov90: "
        "coverage of the 90 % interval; CE 90 %: the central 90 % of the CE over the test shapes drawn with "
        "replacement (how far another draw of as many shapes could move it). Bayesian treats the views' errors "
        "as independent; shared adds back the error they share (fitted on val).",
        ["Method", "Fusion", "views", "shapes", "latent CE", "latent CE 90 %", "latent err/var", "latent cov90"]
        + ["SDF CE", "SDF CE 90 %", "SDF err/var", "SDF cov90"],
    )
    for r in rows:
        table.rows.append(
            [r["label"], r["fusion"], r["n_views"], r["n_shapes"]]
            + [
                value
                for s in ("latent", "sdf")
                for value in (
                    r[f"{s}_calibration_error"],
                    span(r.get(f"{s}_calibration_error_90")),
                    r[f"{s}_error_over_var"],
                    r[f"{s}_coverage90"],
                )
            ]
        )
    return table
