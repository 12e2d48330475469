"""What a protocol is given to score one encoder: its run, encodings by crop scale, the reconstructor, the
split's codes, the records protocols share, and the other protocols' outputs, each computed once.

A reconstruction method (methods.ReconstructionMethod) enters in two places: `encode` gives its per-view
Gaussians (those the rules fuse), and `views` and `after_fusion` its step from a view's or a fused
instance's Gaussian to the one reconstructed, so a protocol that asks through the context scores the method.

Records made here are kept as parts (single views at a crop; instances fused by some rules at a crop),
so the single-view protocol and the corrupted one ask for the same clean views and score them once.
`records()` lists the parts single views first, then fused instances, each in the order first asked for.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from ushape.decoder.artifacts import CodeTable
from ushape.evaluation import protocols as P
from ushape.evaluation.encoders import EncoderRun, split_codes
from ushape.evaluation.methods import per_view
from ushape.evaluation.views import Encodings, Estimate, ViewKey, encode_views
from ushape.fusion.rules import FusedCode

PART_ORDER = ("single", "multi")


class EvalContext:
    """One encoder's evaluation: `protocols` are the asked-for protocol objects, by name."""

    def __init__(self, run: EncoderRun, settings, cache_dir: Path | None, protocols: dict) -> None:
        self.run, self.settings, self.cache_dir = run, settings, cache_dir
        self.protocols = protocols
        self.groups = P.group_views(
            run.keys, settings.group_size, drop_short=bool(run.world.config.get("drop_short_instances"))
        )
        self._encodings: dict[float, Encodings] = {}
        self._estimates: dict[float, dict[ViewKey, Estimate]] = {}
        self._outputs: dict[str, object] = {}
        self._parts: dict[tuple, list[dict]] = {}
        self._codes: CodeTable | None = None

    @property
    def spec(self) -> P.EncoderSpec:
        return self.run.spec

    @property
    def reconstructor(self):
        return self.run.reconstructor

    def asked(self, name: str) -> bool:
        """Whether this evaluation runs protocol `name` for this encoder."""
        return name in self.protocols

    def output(self, name: str):
        """Protocol `name`'s Output for this encoder, run on first asking."""
        if name not in self._outputs:
            self._outputs[name] = self.protocols[name].run(self)
        return self._outputs[name]

    def encode(self, scale: float) -> Encodings:
        """Every test view's Gaussian, each view cropped to a random area in [scale, 1]: the encoder's, or
        the run's reconstruction method's from them (see methods). These are what the fusion rules fuse."""
        if scale not in self._encodings:
            run, settings = self.run, self.settings
            encodings = encode_views(
                run.predictor, run.world, run.keys, scale, settings.seed, self.cache_dir, mask_input=run.mask_input
            )
            self._encodings[scale] = encodings if run.method is None else run.method.encodings(run, encodings, scale)
        return self._encodings[scale]

    def views(self, scale: float, n_views: int | None = None) -> Encodings:
        """Each shape's first n_views test views' Gaussians (None: all) as the run's method reconstructs each
        view on its own (its `after_fusion` step on the view's own crop; var [N, D, D] where the step gives
        full covariances); without such a step, those of `encode(scale)`. What single-view protocols score
        and propagate; each view's step runs once per crop however many protocols ask."""
        encodings = self.encode(scale).first_views(n_views)
        return per_view(self, encodings, scale, self._estimates.setdefault(scale, {}))

    def after_fusion(self, scale: float) -> P.AfterFusion | None:
        """The run's method's step from a fused Gaussian of some views (cropped at `scale`) to the one
        reconstructed; None where there is none (the fused Gaussian is scored as it is)."""
        method = self.run.method
        if method is None or not method.changes_fused:
            return None
        return lambda fused, keys: method.after_fusion(self, fused, keys, scale)

    def fused(self, keys: list[ViewKey], scale: float, rule: Callable[..., FusedCode]) -> Estimate:
        """The views `keys` (cropped at `scale`) fused by `rule`, then passed through the method's step."""
        code = rule(*self.encode(scale).select(keys))
        after = self.after_fusion(scale)
        estimate = Estimate(code.mu, code.var)
        return estimate if after is None else after(estimate, keys)

    def split_codes(self) -> CodeTable:
        """The decoder's codes of the evaluated split (see encoders.split_codes)."""
        if self._codes is None:
            self._codes = split_codes(self.run, self.settings, self.cache_dir)
        return self._codes

    def single_view(self, scale: float) -> list[dict]:
        """Single-view records at a crop scale (the first `single_view_views` views of each shape)."""

        def score() -> list[dict]:
            encodings = self.views(scale, self.settings.single_view_views)
            return P.single_view_records(self.spec, encodings, self.reconstructor, scale, emd=scale == 1.0)

        return self._part(("single", scale), score)

    def multi_view(self, scale: float, methods: dict[str, Callable]) -> list[dict]:
        """Records of every instance fused by each of `methods` (name -> rule) at a crop scale."""

        def score() -> list[dict]:
            return P.multi_view_records(
                self.spec,
                self.encode(scale),
                self.groups,
                methods,
                self.reconstructor,
                scale,
                after=self.after_fusion(scale),
            )

        return self._part(("multi", scale, tuple(methods)), score)

    def records(self) -> list[dict]:
        """Every part made so far: single views first, then fused instances."""
        keys = sorted(self._parts, key=lambda key: PART_ORDER.index(key[0]))
        return [record for key in keys for record in self._parts[key]]

    def _part(self, key: tuple, score: Callable[[], list[dict]]) -> list[dict]:
        if key not in self._parts:
            self._parts[key] = score()
        return self._parts[key]
