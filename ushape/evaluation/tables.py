"""The paper's tables (1, 3, 4, 5, S1) laid out from summarised records, written as CSV and Markdown."""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from ushape import atomic
from ushape.evaluation.protocols import SINGLE_VIEW
from ushape.workspace import TABLES_FILE

ENCODER_ORDER = ("l2", "nll", "es")
TABLE4_SCALES = (1.0, 0.8, 0.4, 0.2, 0.1)
DIFFICULTY = {"Easy": 1.0, "Mid": 0.1, "Hard": 0.01}
NLL_NOTE = (
    "NLL includes the Gaussian constant (a true negative log-likelihood): latent per code, summed over "
    "the D dimensions; SDF per value. ES: multivariate Monte Carlo in latent space, closed-form univariate "
    "in SDF space. SDF values clamped to the decoder's training clamp; variance floored at 1e-6."
)


@dataclass
class Table:
    """A titled grid of cells; numbers are formatted only when written."""

    name: str
    caption: str
    columns: list[str]
    rows: list[list[Any]] = field(default_factory=list)

    def to_csv(self) -> str:
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")
        writer.writerow(self.columns)
        writer.writerows([[_raw(v) for v in row] for row in self.rows])
        return buffer.getvalue()

    def to_markdown(self) -> str:
        lines = [
            f"### {self.name}",
            "",
            "| " + " | ".join(self.columns) + " |",
            "|" + "|".join("---" for _ in self.columns) + "|",
        ]
        lines += ["| " + " | ".join(_cell(v) for v in row) + " |" for row in self.rows]
        return "\n".join(lines + ["", f"*{self.caption}*", ""])


def _raw(value: Any) -> Any:
    return "" if value is None or (isinstance(value, float) and math.isnan(value)) else value


def _cell(value: Any) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    if isinstance(value, float):
        return f"{value:.4f}" if abs(value) < 100 else f"{value:.1f}"
    return str(value)


def _cells(summary: Sequence[dict]) -> dict[tuple, dict]:
    return {(r["encoder"], r["protocol"], r["min_scale"], r["method"]): r for r in summary}


def encoder_order(summary: Sequence[dict]) -> list[tuple[str, str]]:
    seen = {r["encoder"]: r["label"] for r in summary}
    order = [e for e in ENCODER_ORDER if e in seen] + sorted(e for e in seen if e not in ENCODER_ORDER)
    return [(e, seen[e]) for e in order]


def _get(cells: dict, encoder: str, protocol: str, scale: float, method: str, metric: str = "iou") -> float | None:
    cell = cells.get((encoder, protocol, float(scale), method))
    return None if cell is None else cell.get(metric)


def table1(summary: Sequence[dict]) -> Table:
    """Single-view reconstruction: IoU, EMD, CD per encoder (uncorrupted views)."""
    cells = _cells(summary)
    table = Table(
        "Table 1: single-view reconstruction",
        "Pix3D protocol: IoU on 32^3 voxels, EMD and CD on 1024 "
        "surface points, each shape normalised to a centred unit bounding box; mean over the n evaluated test views.",
        ["Method", "Shape", "IoU ↑", "EMD ↓", "CD ↓", "n"],
    )
    for encoder, label in encoder_order(summary):
        cell = cells.get((encoder, "single", 1.0, SINGLE_VIEW))
        if cell is not None:
            table.rows.append([label, "Mesh", cell["iou"], cell.get("emd"), cell.get("cd"), cell["n"]])
    for r in summary:  # the references an encoder sits between (see protocols.reference_records)
        if r["protocol"] == "reference":
            table.rows.append([r["label"], "Mesh", r["iou"], r.get("emd"), r.get("cd"), r["n"]])
    return table


def _improvement(value: float | None, reference: float | None) -> float | None:
    if value is None or not reference:
        return None
    return 100.0 * (value / reference - 1.0)


# Bayesian's mean with the views' shared error added to its variance (docs/fusion_calibration.md): its plain
# IoU is Bayesian's; a refined row starts from its calibrated prior.
TABLE3_NAMES = {"bayesian": "Bayesian(-all)", "shared": "Shared (calibrated Bayesian)"}


def table3(summary: Sequence[dict], group_size: int) -> Table:
    """Multi-view fusion IoU: single view, average, Bayesian-K, Bayesian, shared where the run has it fitted;
    % over FroDO* single/average."""
    cells = _cells(summary)
    table = Table(
        "Table 3: multi-view fusion",
        f"IoU, uncorrupted views; {group_size} views per instance. % is the "
        "improvement over FroDO* (l2) single view / average fusion.",
        ["Encoder", "Views", "Method", "IoU", "%"],
    )
    ref_single = _get(cells, "l2", "single", 1.0, SINGLE_VIEW)
    ref_multi = _get(cells, "l2", "multi", 1.0, "average")
    for encoder, label in encoder_order(summary):
        iou = _get(cells, encoder, "single", 1.0, SINGLE_VIEW)
        if iou is not None:
            table.rows.append([label, 1, "Single-view", iou, _improvement(iou, ref_single)])
        methods = ["average"] + [f"bayesian-{k}" for k in range(1, group_size)] + ["bayesian", "shared"]
        for method in methods:
            iou = _get(cells, encoder, "multi", 1.0, method)
            if iou is not None:
                name = TABLE3_NAMES.get(method, method.capitalize())
                table.rows.append([label, group_size, name, iou, _improvement(iou, ref_multi)])
    return table


def table4(summary: Sequence[dict], k: int = 4, scales: Sequence[float] = TABLE4_SCALES) -> Table:
    """Multi-view IoU under random crops of area [min scale, 1]: FroDO* average, Bayesian and Bayesian-k."""
    cells = _cells(summary)
    table = Table(
        "Table 4: corrupted multi-view",
        "Multi-view IoU when every input view is cropped to a random "
        "area in [min scale, 1.0] (deterministic per view).",
        ["Method"] + [f"{s:g}" for s in scales],
    )
    for encoder, label in encoder_order(summary):
        methods = ["average"] if encoder == "l2" else ["bayesian", f"bayesian-{k}"]
        for method in methods:
            values = [_get(cells, encoder, "multi", s, method) for s in scales]
            if any(v is not None for v in values):
                name = label if encoder == "l2" else f"{label} - {method.capitalize()}"
                table.rows.append([name, *values])
    return table


def table5(summary: Sequence[dict], group_size: int) -> Table:
    """Single- and multi-view IoU on Easy / Mid / Hard crops; Bayesian fusion for Ours, average for FroDO*."""
    cells = _cells(summary)
    table = Table(
        "Table 5: Easy / Mid / Hard",
        "IoU with views cropped to [c, 1.0]: Easy c = 1, Mid c = 0.1, "
        f"Hard c = 0.01. {group_size}-view rows fuse with Bayesian (Ours) or average (FroDO*).",
        ["Method", "Views", *DIFFICULTY],
    )
    for views, protocol in ((1, "single"), (group_size, "multi")):
        for encoder, label in encoder_order(summary):
            method = SINGLE_VIEW if views == 1 else ("average" if encoder == "l2" else "bayesian")
            values = [_get(cells, encoder, protocol, s, method) for s in DIFFICULTY.values()]
            if any(v is not None for v in values):
                table.rows.append([label, views, *values])
    return table


def table_s1(uncertainty: Sequence[dict], summary: Sequence[dict]) -> Table:
    """Uncertainty in SDF space (All / Surface / Non-Surface) beside latent-space scores and single-view IoU."""
    cells = _cells(summary)
    latent = {(r["encoder"], r["variance"]): r for r in uncertainty if r["space"] == "latent"}
    table = Table(
        "Table S1: uncertainty analysis",
        NLL_NOTE + " Equal Var: the same means with latent variance 1. "
        "CE: calibration error (mean |observed - predicted| frequency).",
        [
            "Method",
            "Variance",
            "Propagation",
            "ES all",
            "NLL all",
            "ES surface",
            "NLL surface",
            "ES non-surface",
            "NLL non-surface",
            "CE sdf",
            "ES latent",
            "NLL latent",
            "CE latent",
            "IoU",
        ],
    )
    order = {e: i for i, (e, _) in enumerate(encoder_order(summary or uncertainty))}
    rows = sorted(
        (r for r in uncertainty if r["space"] == "sdf"),
        key=lambda r: (r["variance"] != "equal", order.get(r["encoder"], 99), r["method"]),
    )
    for r in rows:
        lat = latent.get((r["encoder"], r["variance"]), {})
        iou = _get(cells, r["encoder"], "single", 1.0, SINGLE_VIEW) if r["variance"] == "predicted" else None
        name = f"Equal Var ({r['label']} means)" if r["variance"] == "equal" else r["label"]
        table.rows.append(
            [
                name,
                r["variance"],
                r["method"],
                r["es_all"],
                r["nll_all"],
                r["es_surface"],
                r["nll_surface"],
                r["es_non_surface"],
                r["nll_non_surface"],
                r["calibration_error"],
                lat.get("es"),
                lat.get("nll"),
                lat.get("calibration_error"),
                iou,
            ]
        )
    return table


def by_encoder_then_scale(rows: Sequence[dict]) -> list[dict]:
    """Rows in the tables' encoder order, then from the mildest crop (largest min scale) down."""
    order = {e: i for i, (e, _) in enumerate(encoder_order(rows))}
    return sorted(rows, key=lambda r: (order.get(r["encoder"], 99), -r["min_scale"]))


def table_error_tracking(rows: Sequence[dict]) -> Table:
    """Per encoder and crop setting: latent error, shape accuracy, mean predicted covariance trace, and the
    rank correlation of trace and error; pooled rows rank the clean and the cropped views together."""
    table = Table(
        "Table U: does the predicted variance track the error?",
        "Single test views cropped to a random area in [min scale, 1]; '1 & s' pools the clean views with "
        "those cropped at s. Rank corr: Spearman correlation over the views between the covariance trace "
        "and the squared latent error (> 0: the encoder is less sure where it is more wrong). IoU and CD: "
        "the same views' single-view reconstructions (shape space), beside the latent error. A "
        "deterministic encoder has no variance to rank.",
        ["Method", "min scale", "latent L2", "IoU", "CD", "mean var trace", "rank corr", "n"],
    )
    for r in by_encoder_then_scale(rows):
        scale = f"1 & {r['min_scale']:g}" if r.get("pooled") else r["min_scale"]
        table.rows.append(
            [r["label"], scale, r["l2"], r.get("iou"), r.get("cd"), r["var_trace"], r["rank_corr"], r["n"]]
        )
    return table


def table_locality(rows: Sequence[dict]) -> Table:
    """Per probabilistic encoder: does its SDF std sit on the parts a view hides or crops away (see locality)?"""
    table = Table(
        "Table L: where the uncertainty sits",
        "Linearised SDF std on ground-truth surface points of single test views, as ratios of medians "
        "(median over views; in brackets, the share of views above 1). Hidden/visible: occluded vs seen "
        "points. Away/kept: seen points the crop removes vs keeps, with the clean and with the cropped "
        "input; crop shift = cropped / clean (> 1: the crop moved uncertainty onto the removed part). "
        "Std gain: mean std cropped / clean. Error columns: the same ratios of the error |SDF| at the "
        "points, where the prediction really is worse (a calibrated std follows them). Fused: std after "
        "Bayesian fusion of all the shape's views / single view, on the hidden and on the visible points.",
        [
            "Method",
            "min scale",
            "hidden/visible",
            "error hidden/visible",
            "away/kept clean",
            "away/kept cropped",
            "crop shift",
            "error crop shift",
            "std gain",
            "error gain",
            "fused hidden",
            "fused visible",
            "views (cropped)",
        ],
    )

    def cell(r: dict, name: str) -> str | None:
        value, share = r.get(name), r.get(f"{name}_above_1")
        return None if value is None else f"{value:.3f} ({share:.0%})"

    for r in by_encoder_then_scale(rows):
        table.rows.append(
            [
                r["label"],
                r["min_scale"],
                *(
                    cell(r, n)
                    for n in (
                        "hidden_over_visible",
                        "error_hidden_over_visible",
                        "away_over_kept_clean",
                        "away_over_kept_cropped",
                        "crop_shift",
                        "error_crop_shift",
                        "std_gain",
                        "error_gain",
                        "fused_hidden",
                        "fused_visible",
                    )
                ),
                f"{r['n_views']} ({r['n_cropped_views']})",
            ]
        )
    return table


def table_depth(rows: Sequence[dict]) -> Table:
    """Per probabilistic encoder and depth method: is the per-pixel depth std calibrated (see depth_calibration)?"""
    table = Table(
        "Table D: depth uncertainty calibration",
        "Per-pixel depth along each test view's own camera, from the view's latent Gaussian: implicit (one "
        "trace of the mean code, first-order std) or Monte Carlo (M codes traced), against the ground-truth "
        "mesh's depth, over pixels where both hit. Rank corr: Spearman of |error| and std over the pixels. "
        "Coverage: fraction of true depths inside the 68 % / 95 % intervals. CE: calibration error (mean "
        "|observed - predicted| frequency). z = (true - predicted) / std: mean 0, RMS 1 and median |z| 0.674 when "
        "calibrated (RMS z is dominated by the pixels where prediction and truth hit different parts).",
        [
            "Method",
            "Depth method",
            "px",
            "mean abs error",
            "mean std",
            "rank corr",
            "68% cover",
            "95% cover",
            "CE",
            "mean z",
            "RMS z",
            "median abs z",
            "pixels",
            "views",
        ],
    )
    order = {e: i for i, (e, _) in enumerate(encoder_order(rows))}
    for r in sorted(rows, key=lambda r: (order.get(r["encoder"], 99), r["method"])):
        table.rows.append(
            [
                r["label"],
                r["method"],
                r["size"],
                r["mean_abs_error"],
                r["mean_std"],
                r["rank_corr"],
                r["coverage_68"],
                r["coverage_95"],
                r["calibration_error"],
                r["mean_z"],
                r["rms_z"],
                r["median_abs_z"],
                r["n_pixels"],
                r["n_views"],
            ]
        )
    return table


def write_tables(tables: Sequence[Table], out_dir: str | Path) -> Path:
    """Each table as <slug>.csv, and all of them in tables.md; returns the Markdown file."""
    out_dir = Path(out_dir)
    for table in tables:
        atomic.write_text(out_dir / f"{slug(table.name)}.csv", table.to_csv())
    markdown = out_dir / TABLES_FILE
    atomic.write_text(markdown, "\n".join(t.to_markdown() for t in tables))
    return markdown


def slug(name: str) -> str:
    """'Table 3: multi-view fusion' -> 'table3'."""
    head = name.split(":")[0].lower().replace(" ", "")
    return "".join(c for c in head if c.isalnum() or c in "-_")
