"""The depth protocol (Table D): depth std against the true depth error along each test view's own camera.

A reconstruction method is scored on the Gaussian it reconstructs each view with (`context.views`; a full
covariance goes through the depth propagation as it is)."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import ClassVar, Sequence

from ushape.evaluation import plots, tables
from ushape.evaluation.depth_calibration import depth_calibration_rows
from ushape.evaluation.locality import has_cameras
from ushape.evaluation.plugin import Output, Protocol
from ushape.evaluation.uncertainty_protocol import curves_to_json
from ushape.propagation.depth_implicit import DEPTH_METHODS

log = logging.getLogger(__name__)


@dataclass
class Depth(Protocol):
    """size: depth-map pixels per side; views: each shape's first views (None: all); methods: implicit
    and/or mc; codes: Monte Carlo codes traced; steps: sphere-tracing steps per ray."""

    name: ClassVar[str] = "depth"
    size: int = 48
    views: int | None = 2
    methods: Sequence[str] = ("implicit", "mc")
    codes: int = 10
    steps: int = 50

    def __post_init__(self) -> None:
        self.methods = list(self.methods)
        if not set(self.methods) <= set(DEPTH_METHODS) or self.size < 1 or self.codes < 2:
            raise ValueError(
                f"depth: methods must be some of {DEPTH_METHODS}, size >= 1 and codes >= 2; "
                f"got {self.methods}, {self.size}, {self.codes}"
            )

    def run(self, context) -> Output:
        run, settings = context.run, context.settings
        if not has_cameras(run.world, [k.shape_id for k in run.keys]):
            log.warning("Table D skipped: the test renders of %s have no cameras (views.npz)", run.world.root)
            return Output(curves={"depth": {}})
        rows, curves = depth_calibration_rows(
            run.spec,
            context.views(1.0, self.views),
            run.predictor.decoder,
            run.world,
            self.size,
            self.methods,
            self.codes,
            self.steps,
            self.views,
            settings.calibration_levels,
            settings.seed,
        )
        return Output(rows={"depth": rows}, curves={"depth": curves_to_json(curves)})

    def tables(self, result) -> list:
        return [tables.table_depth(result["depth"])] if result.get("depth") else []

    def figures(self, result) -> dict:
        return plots.calibration_figures(result, {"depth": "Calibration, depth"})

    def csvs(self, result) -> dict:
        return {"depth": result.get("depth", [])}
