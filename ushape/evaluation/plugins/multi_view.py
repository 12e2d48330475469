"""The multi-view protocol (Table 3): each instance of group_size clean views fused by every rule, and by
the run's calibrated `shared` rule where `reconstruct.py --fit-temperature` stored it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ushape.evaluation import plots, tables
from ushape.evaluation import protocols as P
from ushape.evaluation.plugin import Output, Protocol
from ushape.evaluation.view_calibration import calibrated_rule


@dataclass
class MultiView(Protocol):
    """Instances of the shared `protocol.group_size` views, fused by average, Bayesian-1..group_size-1 and
    Bayesian."""

    name: ClassVar[str] = "multi_view"

    def run(self, context) -> Output:
        methods = P.fusion_methods(context.spec.probabilistic, range(1, context.settings.group_size))
        context.multi_view(1.0, {**methods, **calibrated_rule(context.run)})
        return Output()

    def tables(self, result) -> list:
        return [tables.table3(result["summary"], result["settings"]["group_size"])]

    def figures(self, result) -> dict:
        summary = result["summary"]
        if not any(r["protocol"] == "multi" and r["min_scale"] == 1.0 for r in summary):
            return {}
        return {"iou_vs_k": plots.iou_vs_k(summary, result["settings"]["group_size"])}
