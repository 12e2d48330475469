"""The uncertainty protocol (Tables S1 and U): latent- and SDF-space scores of the predicted Gaussians with
the equal-variance baseline, and whether the variance tracks the error, clean and (with the corrupted
protocol) at the Easy/Mid/Hard crops, beside the same views' single-view IoU where it was measured.

A reconstruction method's Gaussians are those it reconstructs each view with (`context.views`): a full
covariance goes through the SDF propagation as it is; the latent scores read its diagonal (see
uncertainty_protocol.latent_rows)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from ushape.evaluation import plots, tables
from ushape.evaluation.methods import sdf_variance_calibration
from ushape.evaluation.plugin import Output, Protocol
from ushape.evaluation.uncertainty_protocol import (
    curves_to_json,
    error_tracking_row,
    latent_rows,
    pooled_error_tracking_row,
    sdf_rows,
    with_shape_accuracy,
)

SHAPE_PROTOCOLS = ("single_view", "corrupted")  # whose single-view records give Table U its IoU and CD


@dataclass
class Uncertainty(Protocol):
    """sdf_points: ground-truth SDF samples per view; mc_samples: Monte Carlo codes per prediction;
    sdf_views: each shape's first views (None: all); sdf_clamp: the decoder's training clamp."""

    name: ClassVar[str] = "uncertainty"
    sdf_points: int = 1024
    mc_samples: int = 10
    sdf_views: int | None = None
    sdf_clamp: float | None = 0.1

    def run(self, context) -> Output:
        run, settings = context.run, context.settings
        encodings, codes = context.views(1.0), context.split_codes()
        rows, latent_curves = latent_rows(run.spec, encodings, codes, settings.calibration_levels)
        sdf_temperature, sdf_floor = sdf_variance_calibration(run)
        sdf, sdf_curves = sdf_rows(
            run.spec,
            context.views(1.0, self.sdf_views),
            run.predictor.decoder,
            run.world,
            self.sdf_points,
            self.mc_samples,
            self.sdf_clamp,
            self.sdf_views,
            settings.calibration_levels,
            sdf_temperature=sdf_temperature,
            sdf_floor=sdf_floor,
        )
        for name in SHAPE_PROTOCOLS:
            if context.asked(name):
                context.output(name)
        return Output(
            rows={"uncertainty": rows + sdf, "error_tracking": self.error_tracking(context, codes)},
            curves={"latent": curves_to_json(latent_curves), "sdf": curves_to_json(sdf_curves)},
        )

    @staticmethod
    def error_tracking(context, codes) -> list[dict]:
        corrupted = context.protocols.get("corrupted")
        scales = [1.0] + (list(corrupted.single_view_scales) if corrupted is not None else [])
        spec, clean = context.spec, context.views(1.0)
        tracking = [error_tracking_row(spec, context.views(s), codes, s) for s in dict.fromkeys(scales)]
        tracking += [pooled_error_tracking_row(spec, clean, context.views(s), codes, s) for s in scales if s != 1.0]
        return with_shape_accuracy(tracking, context.records())

    def tables(self, result) -> list:
        built = []
        if result.get("uncertainty"):
            built.append(tables.table_s1(result["uncertainty"], result["summary"]))
        if result.get("error_tracking"):
            built.append(tables.table_error_tracking(result["error_tracking"]))
        return built

    def figures(self, result) -> dict:
        return plots.calibration_figures(
            result, {"latent": "Calibration, latent space", "sdf": "Calibration, SDF space"}
        )

    def csvs(self, result) -> dict:
        return {"uncertainty": result.get("uncertainty", [])}

    def scalars(self, result) -> dict:
        values = {}
        for row in result.get("uncertainty", []):
            tag = f"{row['label']}/uncertainty_{row['space']}_{row['variance']}_{row['method']}"
            for key, value in row.items():
                if isinstance(value, float) and math.isfinite(value):
                    values[f"{tag}/{key}"] = value
        return values
