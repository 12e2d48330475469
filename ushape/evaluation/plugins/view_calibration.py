"""The calibration-across-views protocol (Table V, `eval.py protocols=[view_calibration]`): every fusion rule's
latent and SDF calibration at 1, 3 and 10 fused test views (see evaluation.view_calibration).

A reconstruction method with a step after fusion (a refinement) has every fused subset passed through it;
one without scores the encoder's own fusion again, so its rows are the plain run's and are left out."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ushape.evaluation.plugin import Output, Protocol
from ushape.evaluation.view_calibration import (
    plot_calibration_across_views,
    table_view_calibration,
    view_calibration_protocol,
)


@dataclass
class ViewCalibration(Protocol):
    """draws: random subsets of n distinct views fused per shape and view count n (n = 1: every view);
    k: the Bayesian-K rule's K; sdf_points: ground-truth SDF samples per shape for the SDF columns."""

    name: ClassVar[str] = "view_calibration"
    draws: int = 6
    k: int = 4
    sdf_points: int = 1024

    def run(self, context) -> Output:
        after = context.after_fusion(1.0)
        if context.run.method is not None and after is None:  # the plain run's rows say it
            return Output()
        rows = view_calibration_protocol(
            context.run,
            context.settings.seed,
            context.encode(1.0),
            context.split_codes(),
            self.draws,
            self.k,
            self.sdf_points,
            after,
        )
        return Output(rows={"view_calibration": rows})

    def tables(self, result) -> list:
        return [table_view_calibration(result["view_calibration"])] if result.get("view_calibration") else []

    def figures(self, result) -> dict:
        rows = result.get("view_calibration")
        return {"calibration_across_views": plot_calibration_across_views(rows)} if rows else {}

    def csvs(self, result) -> dict:
        return {"view_calibration": result.get("view_calibration", [])}
