"""The corrupted-views protocol (Tables 4 and 5): single views and fused instances with every input view
cropped to a random area in [min scale, 1], at the corrupted and the Easy/Mid/Hard scales.

Its clean instances are the multi-view protocol's where that one runs too (every rule, Bayesian-K
among them); otherwise it fuses them itself with the rules Table 4 shows.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Sequence

from ushape.evaluation import plots, tables
from ushape.evaluation import protocols as P
from ushape.evaluation.plugin import Output, Protocol


@dataclass
class Corrupted(Protocol):
    """scales: Table 4's crop min scales; k: its Bayesian-K; single_view_scales: Table 5's Easy, Mid and
    Hard crops (the uncertainty protocol's Table U scores the same crops when both run)."""

    name: ClassVar[str] = "corrupted"
    scales: Sequence[float] = (0.8, 0.4, 0.2, 0.1, 0.01)
    k: int = 4
    single_view_scales: Sequence[float] = (1.0, 0.1, 0.01)

    def __post_init__(self) -> None:
        self.scales, self.single_view_scales = list(self.scales), list(self.single_view_scales)
        if self.k < 1 or not all(0 < float(s) <= 1 for s in [*self.scales, *self.single_view_scales]):
            raise ValueError(f"corrupted: k must be >= 1 and every scale in (0, 1]; got {self}")

    def run(self, context) -> Output:
        for scale in dict.fromkeys([1.0, *self.single_view_scales]):
            context.single_view(scale)
        if context.asked("multi_view"):
            context.output("multi_view")
        methods = P.fusion_methods(context.spec.probabilistic, [self.k])
        for scale in dict.fromkeys([*self.scales, *self.single_view_scales]):
            if scale != 1.0 or not context.asked("multi_view"):
                context.multi_view(scale, methods)
        return Output()

    def tables(self, result) -> list:
        summary, group = result["summary"], result["settings"]["group_size"]
        return [tables.table4(summary, self.k), tables.table5(summary, group)]

    def figures(self, result) -> dict:
        summary = result["summary"]
        if len({r["min_scale"] for r in summary if r["protocol"] == "multi"}) <= 1:
            return {}
        return {"iou_vs_min_scale": plots.iou_vs_min_scale(summary, self.k)}
