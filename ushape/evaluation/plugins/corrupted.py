"""The corrupted-views protocol (Tables 4 and 5): single views and fused instances with every input view
cropped to a random area in [min scale, 1], at the corrupted and the Easy/Mid/Hard scales.

Its clean instances are the multi-view protocol's where that one runs too (every rule, Bayesian-K
among them); otherwise it fuses them itself with the rules Table 4 shows.
"""

from __future__ import annotations

from ushape.evaluation import protocols as P
from ushape.evaluation.plugin import Output, Protocol


class Corrupted(Protocol):
    """scales: Table 4's crop min scales; k: its Bayesian-K. The Easy/Mid/Hard scales are the
    preset's single_view_scales, which the uncertainty protocol's Table U shares."""

    name = "corrupted"

    def __init__(self, scales=(0.8, 0.4, 0.2, 0.1, 0.01), k: int = 4) -> None:
        self.scales, self.k = list(scales), k

    def run(self, context) -> Output:
        settings = context.settings
        for scale in dict.fromkeys([1.0, *settings.single_view_scales]):
            context.single_view(scale)
        if context.asked("multi_view"):
            context.output("multi_view")
        methods = P.fusion_methods(context.spec.probabilistic, [self.k])
        for scale in dict.fromkeys([*self.scales, *settings.single_view_scales]):
            if scale != 1.0 or not context.asked("multi_view"):
                context.multi_view(scale, methods)
        return Output()
