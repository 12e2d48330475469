"""The locality protocol (Table L): does the SDF std sit on the parts a view hides or crops away?

A reconstruction method is scored on the Gaussians it reconstructs each view with, clean and cropped
(`context.views`), and on the shape's views fused by the Bayesian rule then passed through its step
(`context.fused`); full covariances are propagated as they are."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import ClassVar

from ushape.evaluation import tables
from ushape.evaluation.locality import has_cameras, locality_records, summarise_locality
from ushape.evaluation.plugin import Output, Protocol
from ushape.fusion.rules import fuse_bayesian

log = logging.getLogger(__name__)


@dataclass
class Locality(Protocol):
    """points: ground-truth surface points per shape; scale: the crops' min area; views: each shape's
    first views only (None: all)."""

    name: ClassVar[str] = "locality"
    points: int = 2048
    scale: float = 0.1
    views: int | None = None

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

        def fused(shape_id: str):
            return context.fused([k for k in run.keys if k.shape_id == shape_id], 1.0, fuse_bayesian)

        views = locality_records(
            run.spec,
            context.views(1.0, self.views),
            context.views(scale, self.views),
            run.predictor.decoder,
            run.world,
            scale,
            settings.seed,
            self.points,
            self.views,
            fuse=fused,
        )
        return Output(rows={"locality_views": views, "locality": summarise_locality(views)})

    def tables(self, result) -> list:
        return [tables.table_locality(result["locality"])] if result.get("locality") else []

    def csvs(self, result) -> dict:
        return {"locality_views": result.get("locality_views", [])}
