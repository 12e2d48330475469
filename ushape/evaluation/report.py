"""Where an evaluation's results go: JSON, CSV and Markdown tables, PNG plots and TensorBoard.

<out_dir>/results.json      everything (records, summary, uncertainty rows, calibration curves)
<out_dir>/records.csv       one row per scored reconstruction
<out_dir>/summary.csv       one row per table cell
<out_dir>/table1.csv ... tables.md   the paper's tables (and ours: tableu, tablel, tabled)
<out_dir>/depth.csv         depth-std calibration per encoder and depth method (Table D)
<out_dir>/eval_row.json     the configured fusion/crop setting's rows (what a sweep gathers)
<out_dir>/plots/*.png       calibration (latent, SDF, depth), IoU vs K, IoU vs min scale
<out_dir>/tensorboard/      the same numbers and figures
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any, Sequence

from ushape import atomic
from ushape.evaluation import active, plots, tables
from ushape.evaluation.active_diagnostics import table_active_why
from ushape.evaluation.settings import RESULT_ROW, RESULTS
from ushape.evaluation.view_calibration import plot_calibration_across_views

PLOTS_DIR = "plots"


def rows_to_csv(rows: Sequence[dict]) -> str:
    """Dicts as CSV; the header is the union of keys in first-seen order."""
    columns = list(dict.fromkeys(k for row in rows for k in row))
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def build_tables(result: dict[str, Any]) -> list[tables.Table]:
    """The paper's tables that this evaluation has numbers for."""
    summary, settings = result["summary"], result["settings"]
    group = settings["group_size"]
    built = [
        tables.table1(summary),
        tables.table3(summary, group),
        tables.table4(summary, settings["table4_k"]),
        tables.table5(summary, group),
    ]
    if result.get("uncertainty"):
        built.append(tables.table_s1(result["uncertainty"], summary))
    if result.get("error_tracking"):
        built.append(tables.table_error_tracking(result["error_tracking"]))
    if result.get("locality"):
        built.append(tables.table_locality(result["locality"]))
    if result.get("depth"):
        built.append(tables.table_depth(result["depth"]))
    if any(r["protocol"] == active.PROTOCOL for r in result["records"]):
        built += [active.table_active(result["records"], metric) for metric in active.METRICS]
    if result.get("active"):
        built.append(table_active_why(result["active"]))
    built += [tables.Table(**table) for table in result.get("tables", [])]  # a plug-in protocol's own
    return [t for t in built if t.rows]


def build_figures(result: dict[str, Any]) -> dict[str, Any]:
    """name -> matplotlib Figure for every plot this evaluation has data for."""
    summary, settings = result["summary"], result["settings"]
    figures = {}
    for space, curves in result.get("curves", {}).items():
        if curves:
            title = {"latent": "Calibration, latent space", "depth": "Calibration, depth"}.get(
                space, "Calibration, SDF space"
            )
            figures[f"calibration_{space}"] = plots.plot_calibration(
                {name: (c["p"], c["freq"]) for name, c in curves.items()}, title
            )
    if any(r["protocol"] == "multi" and r["min_scale"] == 1.0 for r in summary):
        figures["iou_vs_k"] = plots.iou_vs_k(summary, settings["group_size"])
    if len({r["min_scale"] for r in summary if r["protocol"] == "multi"}) > 1:
        figures["iou_vs_min_scale"] = plots.iou_vs_min_scale(summary, settings["table4_k"])
    if result.get("view_calibration"):
        figures["calibration_across_views"] = plot_calibration_across_views(result["view_calibration"])
    if any(r["protocol"] == active.PROTOCOL for r in result["records"]):
        figures["active_iou_vs_views"] = active.plot_active(result["records"])
    return figures


def write_results(result: dict[str, Any], out_dir: str | Path, tensorboard: bool = True) -> dict[str, Path]:
    """Write every output of an evaluation into out_dir; returns the main paths."""
    out_dir = Path(out_dir)
    atomic.write_json(out_dir / RESULTS, _finite(result))
    atomic.write_json(out_dir / RESULT_ROW, _finite(result.get("rows", [])))
    for name in ("records", "summary", "uncertainty", "locality_views", "depth", "view_calibration"):
        if result.get(name):
            atomic.write_text(out_dir / f"{name}.csv", rows_to_csv(result[name]))
    built = build_tables(result)
    paths = {"results": out_dir / RESULTS}
    if built:
        paths["tables"] = tables.write_tables(built, out_dir)
    figures = build_figures(result)
    for name, fig in figures.items():
        plots.save_figure(fig, out_dir / PLOTS_DIR / f"{name}.png")
    if tensorboard:
        paths["tensorboard"] = write_tensorboard(result, built, figures, out_dir / "tensorboard")
    return paths


def write_tensorboard(result: dict[str, Any], built: Sequence[tables.Table], figures: dict, log_dir: Path) -> Path:
    """Summary cells and uncertainty rows as scalars, the plots as figures, the tables as text."""
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(str(log_dir))
    try:
        for row in result["summary"]:
            tag = f"{row['label']}/{row['protocol']}_{row['method']}_scale{row['min_scale']:g}"
            for metric in ("iou", "cd", "emd"):
                if metric in row and math.isfinite(row[metric]):
                    writer.add_scalar(f"{tag}/{metric}", row[metric])
        for row in result.get("uncertainty", []):
            tag = f"{row['label']}/uncertainty_{row['space']}_{row['variance']}_{row['method']}"
            for key, value in row.items():
                if isinstance(value, float) and math.isfinite(value):
                    writer.add_scalar(f"{tag}/{key}", value)
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
