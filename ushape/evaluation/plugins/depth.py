"""The depth protocol (Table D): depth std against the true depth error along each test view's own camera."""

from __future__ import annotations

import logging

from ushape.evaluation.depth_calibration import depth_calibration_rows
from ushape.evaluation.locality import has_cameras
from ushape.evaluation.plugin import Output, Protocol
from ushape.evaluation.uncertainty_protocol import curves_to_json

log = logging.getLogger(__name__)


class Depth(Protocol):
    name = "depth"

    def run(self, context) -> Output:
        run, settings = context.run, context.settings
        if not has_cameras(run.world, [k.shape_id for k in run.keys]):
            log.warning("Table D skipped: the test renders of %s have no cameras (views.npz)", run.world.root)
            return Output(curves={"depth": {}})
        rows, curves = depth_calibration_rows(
            run.spec,
            context.encode(1.0),
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
        return Output(rows={"depth": rows}, curves={"depth": curves_to_json(curves)})
