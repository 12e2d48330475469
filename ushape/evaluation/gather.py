"""Gather an evaluation sweep's result rows into one table.

    python eval.py -m fusion=bayesian_k fusion.k=1,2,4,10 crop.min_scale=1.0,0.1
    ushape gather outputs/multirun/<date>/<time>

Each job folder of the sweep holds eval_row.json (its fusion rule / crop setting's rows, one per
encoder) and .hydra/overrides.yaml (what the job changed); the gathered table has one row per
(job, encoder), written as gathered.csv and gathered.md beside the jobs.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import yaml

from ushape import atomic
from ushape.errors import MissingInputError
from ushape.evaluation.report import rows_to_csv
from ushape.workspace import RESULT_ROW

GATHERED = "gathered"
# Overrides that name folders, not settings: left out of the table's `overrides` column.
FOLDER_KEYS = ("runs", "sweep", "world", "cache_dir", "out_dir")
COLUMNS = (
    "job",
    "overrides",
    "label",
    "fusion",
    "min_scale",
    "single_view_iou",
    "multi_view_iou",
    "single_view_cd",
    "multi_view_cd",
    "n_views",
    "n_instances",
)


def gather_rows(sweep: str | Path) -> list[dict[str, Any]]:
    """One dict per (job, encoder) row of a sweep folder, in job order."""
    sweep = Path(sweep).expanduser()
    if not sweep.is_dir():
        raise MissingInputError(f"sweep folder {sweep} does not exist")
    files = sorted(sweep.rglob(RESULT_ROW), key=lambda p: _job_order(p.parent.relative_to(sweep).as_posix()))
    if not files:
        raise MissingInputError(
            f"no <job>/{RESULT_ROW} under {sweep}: is it an evaluation sweep "
            "(`python eval.py -m ...`)? A training sweep is evaluated with `python eval.py sweep=...`"
        )
    rows = []
    for path in files:
        job = path.parent
        overrides_file = job / ".hydra" / "overrides.yaml"
        overrides = yaml.safe_load(overrides_file.read_text()) if overrides_file.is_file() else []
        for row in json.loads(path.read_text()):
            settings = [o for o in overrides or [] if o.split("=", 1)[0].lstrip("+~") not in FOLDER_KEYS]
            rows.append({"job": job.relative_to(sweep).as_posix(), "overrides": " ".join(settings), **row})
    return rows


def to_markdown(rows: list[dict[str, Any]]) -> str:
    """The gathered rows as a Markdown table (the main columns, numbers to 4 decimals)."""
    columns = [c for c in COLUMNS if any(c in r for r in rows)]
    lines = ["| " + " | ".join(columns) + " |", "|" + "|".join("---" for _ in columns) + "|"]
    for row in rows:
        lines.append("| " + " | ".join(_cell(row.get(c)) for c in columns) + " |")
    return "\n".join(lines) + "\n"


def _cell(value: Any) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.4f}" if isinstance(value, float) else str(value)


def gather(sweep: str | Path) -> Path:
    """Write <sweep>/gathered.csv and gathered.md; returns the Markdown file."""
    sweep = Path(sweep)
    rows = gather_rows(sweep)
    atomic.write_text(sweep / f"{GATHERED}.csv", rows_to_csv(rows))
    markdown = sweep / f"{GATHERED}.md"
    atomic.write_text(markdown, to_markdown(rows))
    return markdown


def _job_order(name: str) -> tuple[int, str]:
    head = name.split("_", 1)[0]
    return (int(head), name) if head.isdigit() else (1 << 30, name)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sweep", help="an evaluation multirun folder, e.g. outputs/multirun/<date>/<time>")
    args = parser.parse_args(argv)
    markdown = gather(args.sweep)
    print(markdown.read_text())
    print(f"written: {markdown} and {markdown.with_suffix('.csv')}")
