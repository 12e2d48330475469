"""The multi-view protocol (Table 3): each instance of group_size clean views fused by every rule, and by
the run's calibrated `shared` rule where `reconstruct.py --fit-temperature` stored it."""

from __future__ import annotations

from ushape.evaluation import protocols as P
from ushape.evaluation.plugin import Output, Protocol
from ushape.evaluation.view_calibration import calibrated_rule


class MultiView(Protocol):
    name = "multi_view"

    def run(self, context) -> Output:
        methods = P.fusion_methods(context.spec.probabilistic, range(1, context.settings.group_size))
        context.multi_view(1.0, {**methods, **calibrated_rule(context.run)})
        return Output()
