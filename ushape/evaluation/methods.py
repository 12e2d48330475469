"""How a view's code becomes a shape, as a dimension of the evaluation's records.

Today's method is the encoder's own Gaussian per view, fused by each table's rule. Another method (a
refinement of each view's code, say) is a `ReconstructionMethod`: given an encoder's encodings at a
crop, it returns the Gaussians the protocols reconstruct and fuse instead. Each encoder is then scored
once plainly and once per method, the latter under the name `<encoder>+<method>` and the label
`<label> + <method label>`, so every table gains the method's rows and no protocol changes.
The active protocol plans with the encoder itself, and meshes and figures are saved for the plain runs.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

from ushape.evaluation.encoders import EncoderRun
from ushape.evaluation.protocols import EncoderSpec
from ushape.evaluation.views import Encodings


class ReconstructionMethod:
    """A method: `name` (in encoder names), `label` (in tables) and `encodings`, which subclasses override."""

    name: str = ""
    label: str = ""

    def encodings(self, run: EncoderRun, encodings: Encodings, min_scale: float) -> Encodings:
        """The Gaussians [N, D] the protocols score for these views (default: the encoder's own)."""
        return encodings


def method_variants(run: EncoderRun, methods: Sequence[ReconstructionMethod]) -> list[EncoderRun]:
    """The run scored plainly, then once per method under its own encoder name and label."""
    variants = [run]
    for method in methods:
        if not method.name:
            raise ValueError(f"{type(method).__name__} needs a name: it tells its rows from the encoder's")
        spec = EncoderSpec(
            f"{run.spec.name}+{method.name}",
            f"{run.spec.label} + {method.label or method.name}",
            run.spec.probabilistic,
        )
        variants.append(replace(run, spec=spec, method=method))
    return variants
