"""The corrupted-views protocol (Tables 4 and 5): single views and fused instances with every input view
cropped to a random area in [min scale, 1], at the corrupted and the Easy/Mid/Hard scales.

Its clean instances are the multi-view protocol's where that one runs too (every rule, Bayesian-K
among them); otherwise it fuses them itself with the rules Table 4 shows.
"""

from __future__ import annotations

from ushape.evaluation import protocols as P
from ushape.evaluation.plugin import Output, Protocol


class Corrupted(Protocol):
    name = "corrupted"

    def run(self, context) -> Output:
        settings = context.settings
        for scale in dict.fromkeys([1.0, *settings.single_view_scales]):
            context.single_view(scale)
        if context.asked("multi_view"):
            context.output("multi_view")
        methods = P.fusion_methods(context.spec.probabilistic, [settings.table4_k])
        for scale in dict.fromkeys([*settings.corrupted_scales, *settings.single_view_scales]):
            if scale != 1.0 or not context.asked("multi_view"):
                context.multi_view(scale, methods)
        return Output()
