"""The depth protocol (Table D): depth std against the true depth error along each test view's own camera.

A reconstruction method is scored on the Gaussian it reconstructs each view with (`context.views`; a full
covariance goes through the depth propagation as it is)."""

from __future__ import annotations

import logging

from ushape.evaluation.depth_calibration import depth_calibration_rows
from ushape.evaluation.locality import has_cameras
from ushape.evaluation.plugin import Output, Protocol
from ushape.evaluation.uncertainty_protocol import curves_to_json

log = logging.getLogger(__name__)


class Depth(Protocol):
    """size: depth-map pixels per side; views: each shape's first views (None: all); methods: implicit
    and/or mc; codes: Monte Carlo codes traced; steps: sphere-tracing steps per ray."""

    name = "depth"

    def __init__(
        self, size: int = 48, views: int | None = 2, methods=("implicit", "mc"), codes: int = 10, steps: int = 50
    ) -> None:
        self.size, self.views, self.methods, self.codes, self.steps = size, views, list(methods), codes, steps

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
