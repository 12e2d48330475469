"""Figures of an evaluation: IoU against K (Bayesian-K), IoU against the crop's min scale, calibration."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from ushape.evaluation.tables import encoder_order
from ushape.metrics.calibration import plot_calibration

__all__ = ["calibration_figures", "iou_vs_k", "iou_vs_min_scale", "plot_calibration", "save_figure"]


def _figure():
    from matplotlib.figure import Figure  # pyplot-free: no global state, no GUI backend

    fig = Figure(figsize=(5, 3.6))
    return fig, fig.add_subplot()


def calibration_figures(result: dict, spaces: dict[str, str]) -> dict:
    """calibration_<space> -> the reliability diagram (titled spaces[space]) of every encoder's curves in that
    space of an evaluation's result, for each space that has curves."""
    curves = result.get("curves", {})
    return {
        f"calibration_{space}": plot_calibration(
            {name: (c["p"], c["freq"]) for name, c in curves[space].items()}, title
        )
        for space, title in spaces.items()
        if curves.get(space)
    }


def iou_vs_k(summary: Sequence[dict], group_size: int, min_scale: float = 1.0):
    """Multi-view IoU of Bayesian-K against K (K = all views at the right), with average fusion dashed."""
    fig, ax = _figure()
    for encoder, label in encoder_order(summary):
        cells = {
            r["method"]: r["iou"]
            for r in summary
            if r["encoder"] == encoder and r["protocol"] == "multi" and r["min_scale"] == min_scale
        }
        ks = [k for k in range(1, group_size) if f"bayesian-{k}" in cells]
        if "bayesian" in cells:
            xs, ys = ks + [group_size], [cells[f"bayesian-{k}"] for k in ks] + [cells["bayesian"]]
            (line,) = ax.plot(xs, ys, marker="o", label=f"{label} Bayesian-K")
            colour = line.get_color()
        else:
            colour = None
        if "average" in cells:
            ax.axhline(cells["average"], linestyle="--", color=colour, label=f"{label} average")
    ax.set(xlabel="K (views kept)", ylabel="IoU", title=f"Multi-view IoU vs K (min scale {min_scale:g})")
    ax.legend(fontsize="small")
    fig.tight_layout()
    return fig


def iou_vs_min_scale(summary: Sequence[dict], k: int = 4):
    """Multi-view IoU against the crop's min scale: average for FroDO*, Bayesian and Bayesian-k for the others."""
    fig, ax = _figure()
    for encoder, label in encoder_order(summary):
        methods = ["average"] if encoder == "l2" else ["bayesian", f"bayesian-{k}"]
        for method in methods:
            points = sorted(
                (r["min_scale"], r["iou"])
                for r in summary
                if r["encoder"] == encoder and r["protocol"] == "multi" and r["method"] == method
            )
            if points:
                ax.plot(*zip(*points), marker="o", label=f"{label} {method}")
    ax.set_xscale("log")
    ax.invert_xaxis()  # harder (smaller crops) to the right
    ax.set(xlabel="min scale of the random crop (log)", ylabel="IoU", title="Multi-view IoU vs corruption")
    ax.legend(fontsize="small")
    fig.tight_layout()
    return fig


def save_figure(fig, path: str | Path) -> Path:
    """Write a Figure as PNG (atomically: the file appears complete or not at all)."""
    from ushape import atomic

    path = Path(path)
    with atomic.atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    return path
