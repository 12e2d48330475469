"""Where an evaluation's results go: JSON, CSV and Markdown tables, PNG plots and TensorBoard.

<out_dir>/results.json      everything (records, summary, uncertainty rows, calibration curves)
<out_dir>/records.csv       one row per scored reconstruction
<out_dir>/summary.csv       one row per table cell
<out_dir>/table1.csv ... tables.md   every protocol's tables (the paper's, and ours: tableu, tablel, tabled, ...)
<out_dir>/<rows>.csv        a protocol's own rows (uncertainty.csv, depth.csv, ...: its `csvs` hook)
<out_dir>/eval_row.json     the configured fusion/crop setting's rows (what a sweep gathers)
<out_dir>/plots/*.png       every protocol's figures (calibration, IoU vs K, IoU vs min scale, ...)
<out_dir>/tensorboard/      the summary cells, every protocol's scalars, the figures and the tables

Which tables, CSVs, figures and scalars there are is each protocol's own business (evaluation.plugin):
this module loops over the protocols recorded in the result.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any, Sequence

from ushape import atomic
from ushape.evaluation import plots, tables
from ushape.evaluation.plugin import Protocol, protocols_of
from ushape.workspace import RESULT_ROW, RESULTS

PLOTS_DIR = "plots"


def rows_to_csv(rows: Sequence[dict]) -> str:
    """Dicts as CSV; the header is the union of keys in first-seen order."""
    columns = list(dict.fromkeys(k for row in rows for k in row))
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def build_tables(result: dict[str, Any], protocols: Sequence[Protocol] | None = None) -> list[tables.Table]:
    """Every table the evaluation's protocols have numbers for, protocol by protocol in the order they ran
    (protocols: those of the result, already built; None: built again from it)."""
    protocols = protocols_of(result) if protocols is None else protocols
    built = [table for protocol in protocols for table in protocol.tables(result)]
    return [t for t in built if t.rows]


def build_figures(result: dict[str, Any], protocols: Sequence[Protocol] | None = None) -> dict[str, Any]:
    """name -> matplotlib Figure for every plot the evaluation's protocols have data for (protocols: as
    build_tables')."""
    protocols = protocols_of(result) if protocols is None else protocols
    return {name: fig for protocol in protocols for name, fig in protocol.figures(result).items()}


def write_results(result: dict[str, Any], out_dir: str | Path, tensorboard: bool = True) -> dict[str, Path]:
    """Write every output of an evaluation into out_dir; returns the main paths."""
    out_dir = Path(out_dir)
    atomic.write_json(out_dir / RESULTS, _finite(result))
    atomic.write_json(out_dir / RESULT_ROW, _finite(result.get("rows", [])))
    protocols = protocols_of(result)  # built once, for every output below
    csvs = {"records": result["records"], "summary": result["summary"]}
    for protocol in protocols:
        csvs.update(protocol.csvs(result))
    for name, rows in csvs.items():
        if rows:
            atomic.write_text(out_dir / f"{name}.csv", rows_to_csv(rows))
    built = build_tables(result, protocols)
    paths = {"results": out_dir / RESULTS}
    if built:
        paths["tables"] = tables.write_tables(built, out_dir)
    figures = build_figures(result, protocols)
    for name, fig in figures.items():
        plots.save_figure(fig, out_dir / PLOTS_DIR / f"{name}.png")
    if tensorboard:
        paths["tensorboard"] = write_tensorboard(result, protocols, built, figures, out_dir / "tensorboard")
    return paths


def write_tensorboard(
    result: dict[str, Any], protocols: Sequence[Protocol], built: Sequence[tables.Table], figures: dict, log_dir: Path
) -> Path:
    """Summary cells and uncertainty rows as scalars, the plots as figures, the tables as text."""
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(str(log_dir))
    try:
        for row in result["summary"]:
            tag = f"{row['label']}/{row['protocol']}_{row['method']}_scale{row['min_scale']:g}"
            for metric in ("iou", "cd", "emd"):
                if metric in row and math.isfinite(row[metric]):
                    writer.add_scalar(f"{tag}/{metric}", row[metric])
        for protocol in protocols:
            for tag, value in protocol.scalars(result).items():
                writer.add_scalar(tag, value)
        for row in result.get("rows", []):
            writer.add_scalar(
                f"{row['label']}/sweep_{row['fusion']}_scale{row['min_scale']:g}/multi_view_iou", row["multi_view_iou"]
            )
        for name, fig in figures.items():
            writer.add_figure(f"eval/{name}", fig)
        for table in built:
            writer.add_text(f"tables/{tables.slug(table.name)}", table.to_markdown())
    finally:
        writer.close()
    return log_dir


def _finite(obj: Any) -> Any:
    """NaN/inf -> None so results.json is strict JSON (readable by any tool, not only Python)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj
