"""The single-view protocol (Table 1): every clean test view reconstructed from its own code."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Sequence

from ushape.decoder.artifacts import codes_file, load_codes
from ushape.evaluation import protocols as P
from ushape.evaluation import tables
from ushape.evaluation.encoders import split_codes
from ushape.evaluation.plugin import Output, Protocol


@dataclass
class SingleView(Protocol):
    """Scores each shape's first `protocol.single_view_views` clean views (the shared setting: the corrupted
    protocol and the sweep row score the same views)."""

    name: ClassVar[str] = "single_view"

    def run(self, context) -> Output:
        context.single_view(1.0)
        return Output()

    def after_all(self, runs: Sequence, settings, cache_dir: Path | None) -> list[dict]:
        """Table 1's reference rows from the first run's decoder: the test shapes' own codes and the mean code."""
        if not runs:
            return []
        run = runs[0]
        codes = split_codes(run, settings, cache_dir)
        train = load_codes(run.codes_dir / codes_file("train"))
        shape_ids = list(dict.fromkeys(k.shape_id for k in run.keys))
        return P.reference_records(codes, train, shape_ids, run.reconstructor)

    def tables(self, result) -> list:
        return [tables.table1(result["summary"])]
