"""The active protocol (Table A, `eval.py protocols=[active]`): next-best-view strategies compared
(see evaluation.active), Table A-why, and the first shape's sequence saved as a figure.

Its settings are the plan's (planning.sequence.ActivePlan): ++plugins.active.views=..., .strategies=[...], ..."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from ushape.evaluation.active import active_records, save_active_sequence
from ushape.evaluation.active_diagnostics import table_active_why
from ushape.evaluation.active_tables import METRICS, PROTOCOL, plot_active, table_active
from ushape.evaluation.plugin import Output, Protocol
from ushape.planning.sequence import ActivePlan


@dataclass
class Active(ActivePlan, Protocol):
    name: ClassVar[str] = PROTOCOL

    def run(self, context) -> Output:
        if context.run.method is not None:  # it plans with the encoder itself: the plain run's rows say it
            return Output()
        records, diagnostics = active_records(
            context.run, context.settings, self, context.split_codes(), context.cache_dir
        )
        return Output(records=records, rows={"active": diagnostics})

    def save_figures(self, run, settings, out_dir: Path) -> list[Path]:
        return save_active_sequence(run, settings, self, out_dir)

    def _ran(self, result) -> bool:
        return any(r["protocol"] == PROTOCOL for r in result["records"])

    def tables(self, result) -> list:
        built = [table_active(result["records"], metric) for metric in METRICS] if self._ran(result) else []
        return built + ([table_active_why(result["active"])] if result.get("active") else [])

    def figures(self, result) -> dict:
        return {"active_iou_vs_views": plot_active(result["records"])} if self._ran(result) else {}
