"""The uncertainty analysis (the paper's Table S1 and calibration plots) over single test views.

For each encoder, its predicted latent Gaussians and the equal-variance baseline (var = 1, the
same means) are scored against the stage-1 codes in latent space, and propagated through the
decoder to the ground-truth SDF sample points of each shape (Monte Carlo, and linearised as a
second method) and scored there per SDF value, split into All / Surface / Non-Surface.

A method's full covariance [D, D] (a refined posterior) is propagated to SDF space as it is. The latent
scores read its diagonal, explicitly (`Encodings.marginal_var`): the per-dimension calibration and the
covariance trace need only the marginals, but the latent ES and NLL then treat the dimensions as
independent, so for a full covariance they score its marginals, not the joint Gaussian.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor
from tqdm.auto import tqdm

from ushape.data.layout import WorldIndex
from ushape.data.sdf_dataset import sdf_points
from ushape.decoder.artifacts import CodeTable
from ushape.encoder.latent_metrics import latent_l2, variance_tracks_error
from ushape.evaluation.protocols import EncoderSpec, summarise
from ushape.evaluation.uncertainty import EQUAL_VARIANCE, latent_report, sdf_region_scores
from ushape.evaluation.views import Encodings
from ushape.metrics.calibration import calibration_curve, calibration_error
from ushape.propagation import SDF_CLAMP, propagate_to_sdf
from ushape.recalibration import apply_temperature

PROPAGATION_METHODS = ("mc", "linearised")


def _variants(spec: EncoderSpec, var: Tensor) -> dict[str, Tensor]:
    """Predicted variance ([N, D] or [N, D, D]) and the equal-variance baseline [N, D]; a deterministic encoder
    only has the latter."""
    equal = torch.full(var.shape[:2], EQUAL_VARIANCE, dtype=var.dtype)
    return {"predicted": var, "equal": equal} if spec.probabilistic else {"equal": equal}


def code_targets(encodings: Encodings, codes: CodeTable) -> Tensor:
    """The stage-1 code of each encoded view's shape. -> [N, D]"""
    return torch.stack([codes.lookup(k.shape_id) for k in encodings.keys])


def latent_rows(spec: EncoderSpec, encodings: Encodings, codes: CodeTable, n_levels: int = 20) -> tuple[list, dict]:
    """Latent-space ES / NLL / L2 / calibration error per variance variant, and their calibration curves
    (of each dimension's marginal: a full covariance's diagonal, see the module docstring)."""
    target = code_targets(encodings, codes)
    rows, curves = [], {}
    for variant, var in _variants(spec, encodings.marginal_var).items():
        report = latent_report(encodings.mu, var, target, n_levels=n_levels)
        rows.append(
            {"encoder": spec.name, "label": spec.label, "variance": variant, "space": "latent", "method": "-", **report}
        )
        curves[f"{spec.label} ({variant} var)"] = calibration_curve((encodings.mu - target).abs(), var.sqrt(), n_levels)
    return rows, curves


def error_tracking_row(spec: EncoderSpec, encodings: Encodings, codes: CodeTable, min_scale: float) -> dict:
    """Does the predicted variance grow with the error? Spearman rank correlation, over the views, of the
    covariance trace against the squared latent error, at one crop setting (NaN for a constant variance)."""
    target = code_targets(encodings, codes)
    var = encodings.marginal_var  # the trace is the diagonal's sum, full covariance or not
    rank_corr = variance_tracks_error(var, encodings.mu, target) if spec.probabilistic else float("nan")
    return {
        "encoder": spec.name,
        "label": spec.label,
        "min_scale": float(min_scale),
        "n": len(encodings.keys),
        "l2": float(latent_l2(encodings.mu, target)),
        "var_trace": float(var.sum(-1).mean()),
        "rank_corr": float(rank_corr),
    }


def pooled_error_tracking_row(
    spec: EncoderSpec, clean: Encodings, cropped: Encodings, codes: CodeTable, min_scale: float
) -> dict:
    """`error_tracking_row` over the clean and the cropped views together: whether the variance ranks a
    view's error both across shapes and across how much of the object the view shows."""
    var = torch.cat([clean.marginal_var, cropped.marginal_var])  # all the row reads of a full covariance
    both = Encodings(clean.keys + cropped.keys, torch.cat([clean.mu, cropped.mu]), var)
    return {**error_tracking_row(spec, both, codes, min_scale), "pooled": True}


def with_shape_accuracy(rows: list[dict], records: list[dict]) -> list[dict]:
    """Each error-tracking row with the mean single-view IoU and Chamfer of the same encoder and crop
    (latent error alone misleads where codes are not identifiable); None where none was measured."""
    cells = {(r["encoder"], r["min_scale"]): r for r in summarise(x for x in records if x["protocol"] == "single")}
    out = []
    for row in rows:
        scales = [row["min_scale"]] if not row.get("pooled") else [1.0, row["min_scale"]]
        found = [cells.get((row["encoder"], s)) for s in scales]
        found = [f for f in found if f is not None]
        n = sum(f["n"] for f in found)
        out.append(
            {
                **row,
                "iou": sum(f["iou"] * f["n"] for f in found) / n if n else None,
                "cd": sum(f["cd"] * f["n"] for f in found) / n if n else None,
            }
        )
    return out


def sdf_rows(
    spec: EncoderSpec,
    encodings: Encodings,
    decoder,
    world: WorldIndex,
    n_points: int = 1024,
    n_samples: int = 10,
    clamp: float | None = SDF_CLAMP,
    views_per_shape: int | None = None,
    n_levels: int = 20,
    methods: tuple[str, ...] = PROPAGATION_METHODS,
    sdf_temperature: float | None = None,
    sdf_floor: float | None = None,
) -> tuple[list, dict]:
    """SDF-space ES / NLL per region and calibration error, per (variance variant, propagation method).

    `sdf_temperature` (`fit_and_store_temperature`'s, fitted on val) scales the predicted SDF variance, and
    `sdf_floor` (a std, fitted with it for a method's Gaussians) is added to it: T_sdf var + floor^2.
    """
    encodings = encodings.first_views(views_per_shape)
    pools: dict[tuple[str, str], list[tuple[Tensor, Tensor, Tensor]]] = {}
    for i, key in enumerate(tqdm(encodings.keys, desc=f"{spec.name} SDF uncertainty", leave=False)):
        points, sdf_true = sdf_points(world, key.shape_id, n_points)
        if clamp is not None:
            sdf_true = sdf_true.clamp(-clamp, clamp)
        for variant, var in _variants(spec, encodings.var[i : i + 1]).items():
            # The equal-variance baseline by Monte Carlo only: it is the paper's baseline, not a method.
            for method in methods if variant == "predicted" else ("mc",):
                mean, variance = propagate_to_sdf(
                    decoder, encodings.mu[i], var[0], points, method, n_samples, seed=i, clamp=clamp
                )
                if variant == "predicted" and sdf_temperature is not None:
                    variance = apply_temperature(variance, sdf_temperature)
                if variant == "predicted" and sdf_floor is not None:
                    variance = variance + sdf_floor**2
                pools.setdefault((variant, method), []).append((mean, variance, sdf_true))
    rows, curves = [], {}
    for (variant, method), parts in pools.items():
        mean, variance, sdf_true = (torch.cat(t) for t in zip(*parts))
        p, freq = calibration_curve((mean - sdf_true).abs(), variance.sqrt(), n_levels)
        rows.append(
            {
                "encoder": spec.name,
                "label": spec.label,
                "variance": variant,
                "space": "sdf",
                "method": method,
                **sdf_region_scores(mean, variance, sdf_true),
                "calibration_error": calibration_error(p, freq),
            }
        )
        curves[f"{spec.label} ({variant} var, {method})"] = (p, freq)
    return rows, curves


def curves_to_json(curves: dict[str, tuple[Tensor, Tensor]]) -> dict[str, dict[str, list[float]]]:
    """Calibration curves as plain lists, for results.json and the notebook."""
    return {
        name: {"p": torch.as_tensor(p).tolist(), "freq": torch.as_tensor(f).tolist()} for name, (p, f) in curves.items()
    }


def decoder_dir_of(predictor) -> Path:
    """The stage-1 decoder folder the encoder was trained against (holds codes_test.pt)."""
    path = Path(predictor.model.hparams.decoder_path)
    return path if path.is_dir() else path.parent
