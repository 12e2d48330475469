"""The active protocol (Table A, `eval.py protocols=[active]`): next-best-view strategies compared
(see evaluation.active), and the first shape's sequence saved as a figure."""

from __future__ import annotations

from pathlib import Path

from ushape.evaluation.active import active_records, save_active_sequence
from ushape.evaluation.plugin import Output, Protocol


class Active(Protocol):
    name = "active"

    def run(self, context) -> Output:
        if context.run.method is not None:  # it plans with the encoder itself: the plain run's rows say it
            return Output()
        records, diagnostics = active_records(context.run, context.settings, context.split_codes(), context.cache_dir)
        return Output(records=records, rows={"active": diagnostics})

    def save_figures(self, run, settings, out_dir: Path) -> list[Path]:
        return save_active_sequence(run, settings, out_dir)
