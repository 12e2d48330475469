"""The calibration-across-views protocol (Table V, `eval.py protocols=[view_calibration]`): every fusion rule's
latent and SDF calibration at 1, 3 and 10 fused test views (see evaluation.view_calibration).

A reconstruction method with a step after fusion (a refinement) has every fused subset passed through it;
one without scores the encoder's own fusion again, so its rows are the plain run's and are left out."""

from __future__ import annotations

from ushape.evaluation.plugin import Output, Protocol
from ushape.evaluation.view_calibration import table_view_calibration, view_calibration_protocol


class ViewCalibration(Protocol):
    """draws: random subsets of n distinct views fused per shape and view count n (n = 1: every view)."""

    name = "view_calibration"

    def __init__(self, draws: int = 6) -> None:
        self.draws = draws

    def run(self, context) -> Output:
        after = context.after_fusion(1.0)
        if context.run.method is not None and after is None:  # the plain run's rows say it
            return Output()
        rows = view_calibration_protocol(
            context.run, context.settings, context.encode(1.0), context.split_codes(), self.draws, after
        )
        return Output(rows={"view_calibration": rows})

    def tables(self, result) -> list:
        return [table_view_calibration(result["view_calibration"])] if result.get("view_calibration") else []
