"""The locality protocol (Table L): does the SDF std sit on the parts a view hides or crops away?"""

from __future__ import annotations

import logging

from ushape.evaluation.locality import has_cameras, locality_records, summarise_locality
from ushape.evaluation.plugin import Output, Protocol

log = logging.getLogger(__name__)


class Locality(Protocol):
    """points: ground-truth surface points per shape; scale: the crops' min area; views: each shape's
    first views only (None: all)."""

    name = "locality"

    def __init__(self, points: int = 2048, scale: float = 0.1, views: int | None = None) -> None:
        self.points, self.scale, self.views = points, scale, views

    def run(self, context) -> Output:
        run, settings = context.run, context.settings
        if not has_cameras(run.world, [k.shape_id for k in run.keys]):
            log.warning(
                "Table L skipped: the test renders of %s have no cameras (views.npz), so which parts a "
                "view hides or crops away is unknown",
                run.world.root,
            )
            return Output()
        scale = self.scale
        views = locality_records(
            run.spec,
            context.encode(1.0),
            context.encode(scale),
            run.predictor.decoder,
            run.world,
            scale,
            settings.seed,
            self.points,
            self.views,
        )
        return Output(rows={"locality_views": views, "locality": summarise_locality(views)})
