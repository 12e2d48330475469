"""The locality protocol (Table L): does the SDF std sit on the parts a view hides or crops away?"""

from __future__ import annotations

import logging

from ushape.evaluation.locality import has_cameras, locality_records, summarise_locality
from ushape.evaluation.plugin import Output, Protocol

log = logging.getLogger(__name__)


class Locality(Protocol):
    name = "locality"

    def run(self, context) -> Output:
        run, settings = context.run, context.settings
        if not has_cameras(run.world, [k.shape_id for k in run.keys]):
            log.warning(
                "Table L skipped: the test renders of %s have no cameras (views.npz), so which parts a "
                "view hides or crops away is unknown",
                run.world.root,
            )
            return Output()
        scale = settings.locality_scale
        views = locality_records(
            run.spec,
            context.encode(1.0),
            context.encode(scale),
            run.predictor.decoder,
            run.world,
            scale,
            settings.seed,
            settings.locality_points,
            settings.locality_views,
        )
        return Output(rows={"locality_views": views, "locality": summarise_locality(views)})
