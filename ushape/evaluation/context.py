"""What a protocol is given to score one encoder: its run, encodings by crop scale, the reconstructor, the
split's codes, the records protocols share, and the other protocols' outputs, each computed once.

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
from ushape.evaluation.views import Encodings, encode_views

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
        the run's reconstruction method's from them (see methods)."""
        if scale not in self._encodings:
            run, settings = self.run, self.settings
            encodings = encode_views(
                run.predictor, run.world, run.keys, scale, settings.seed, self.cache_dir, mask_input=run.mask_input
            )
            self._encodings[scale] = encodings if run.method is None else run.method.encodings(run, encodings, scale)
        return self._encodings[scale]

    def split_codes(self) -> CodeTable:
        """The decoder's codes of the evaluated split (see encoders.split_codes)."""
        if self._codes is None:
            self._codes = split_codes(self.run, self.settings, self.cache_dir)
        return self._codes

    def single_view(self, scale: float) -> list[dict]:
        """Single-view records at a crop scale (the first `single_view_views` views of each shape)."""

        def score() -> list[dict]:
            encodings = self.encode(scale).first_views(self.settings.single_view_views)
            return P.single_view_records(self.spec, encodings, self.reconstructor, scale, emd=scale == 1.0)

        return self._part(("single", scale), score)

    def multi_view(self, scale: float, methods: dict[str, Callable]) -> list[dict]:
        """Records of every instance fused by each of `methods` (name -> rule) at a crop scale."""

        def score() -> list[dict]:
            return P.multi_view_records(self.spec, self.encode(scale), self.groups, methods, self.reconstructor, scale)

        return self._part(("multi", scale, tuple(methods)), score)

    def records(self) -> list[dict]:
        """Every part made so far: single views first, then fused instances."""
        keys = sorted(self._parts, key=lambda key: PART_ORDER.index(key[0]))
        return [record for key in keys for record in self._parts[key]]

    def _part(self, key: tuple, score: Callable[[], list[dict]]) -> list[dict]:
        if key not in self._parts:
            self._parts[key] = score()
        return self._parts[key]
