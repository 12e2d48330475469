"""Table A and its plot: the active protocol's records (one per shape, crop, strategy and views taken) laid
out as per-view means, paired gains against random, the views needed to reach random, and the step time."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ushape.evaluation.tables import Table, encoder_order
from ushape.planning.plugins import is_oracle

PROTOCOL = "active"
REFERENCE = "random"

# metric -> (its name in the tables, +1 where higher is better, -1 where lower is)
METRICS = {"iou": ("IoU", 1), "cd": ("CD", -1)}


def curves(records: Sequence[dict], metric: str = "iou") -> dict[tuple, dict[int, list[float]]]:
    """(encoder, min scale, strategy) -> views -> the metric per shape, in shape order (NaN: empty mesh)."""
    out: dict[tuple, dict[int, list[float]]] = {}
    for r in records:
        if r["protocol"] == PROTOCOL:
            value = r.get(metric)
            value = math.nan if value is None else float(value)
            out.setdefault((r["encoder"], r["min_scale"], r["method"]), {}).setdefault(r["views"], []).append(value)
    return out


def views_to_reach(means: dict[int, float], target: float, sign: int = 1) -> int | None:
    """The fewest views whose mean reaches target (sign -1: at or below it); None: none does."""
    return next((k for k in sorted(means) if sign * means[k] >= sign * target - 1e-12), None)


def standard_error(values: Sequence[float]) -> float:
    """Standard error of the mean of the finite values (0 for fewer than two)."""
    values = np.asarray(values, np.float64)
    values = values[np.isfinite(values)]
    return float(np.std(values, ddof=1) / math.sqrt(len(values))) if len(values) > 1 else 0.0


def paired_gain(curve: dict[int, list[float]], reference: dict[int, list[float]], sign: int = 1) -> tuple[float, float]:
    """Mean per-shape improvement over the reference across views 2..N (sign -1: a drop is the improvement),
    and its standard error over shapes; shapes with an empty mesh at some view average the other views."""
    views = [k for k in sorted(curve) if k > 1 and k in reference]
    if not views:
        return math.nan, math.nan
    with np.errstate(invalid="ignore"):
        per_view = sign * np.subtract([curve[k] for k in views], [reference[k] for k in views])  # [views, shapes]
        finite = np.isfinite(per_view).any(axis=0)
        if not finite.any():
            return math.nan, math.nan
        gains = np.nanmean(per_view[:, finite], axis=0)
    return float(gains.mean()), standard_error(gains) if len(gains) > 1 else math.nan


def step_seconds(curve: dict[int, list[float]]) -> float | None:
    """Mean wall time of a step after the first (choosing the view and forming the belief after it)."""
    values = [v for k, vs in curve.items() if k > 1 for v in vs if math.isfinite(v)]
    return float(np.mean(values)) if values else None


def reference_of(method: str) -> str:
    """The row a method is compared with: random under the same observer (its belief refined alike)."""
    _, plus, observe = method.partition("+")
    return REFERENCE + plus + observe


def table_active(records: Sequence[dict], metric: str = "iou") -> Table:
    """Table A: the metric after 1..N views per strategy (mean over shapes; sd at N), and against random."""
    name, sign = METRICS[metric]
    data = curves(records, metric)
    n = max((max(c) for c in data.values()), default=0)
    reach = n - 1 if n > 2 else n
    table = Table(
        f"Table A: active reconstruction ({name} after k views)",
        "Each held-out shape starts from the same view for every strategy; views fused by the Bayesian rule "
        "(refined rows: the run's calibrated shared rule where fitted, the prior reconstruct.py refines). "
        f"'gain vs random': mean per-shape {name} {'gain' if sign > 0 else 'drop'} against random over views "
        f"2-{n}, +- its standard error over shapes (positive: better than random). 'views to reach': the fewest "
        f"views whose mean {name} reaches random's at {reach} views. The oracles look at the answer (oracle: "
        "the belief's distance from the shape's own code; oracle-occupancy: its shape's): no robot could run them. "
        "'strategy+masks' / '+depth': the belief after each view is the fused Gaussian refined on every view taken "
        "(compared with random+masks / +depth). 's / step': mean seconds of a step after the first (scoring the "
        "candidates, then fusing and refining).",
        ["Encoder", "min scale", "strategy", *[f"{name} {k}" for k in range(1, n + 1)], f"sd {n}", "shapes"]
        + ["gain vs random", "s.e.", f"views to reach random@{reach}", "s / step"],
    )
    timing = curves(records, "seconds")
    labels = dict(encoder_order([{"encoder": r["encoder"], "label": r["label"]} for r in records]))
    for (encoder, scale, method), curve in sorted(data.items(), key=lambda item: (item[0][0], -item[0][1])):
        means = {k: float(np.nanmean(v)) for k, v in curve.items()}
        baseline = reference_of(method)
        reference = data.get((encoder, scale, baseline), {})
        gain, se = paired_gain(curve, reference, sign) if method != baseline else (math.nan, math.nan)
        target = float(np.nanmean(reference[reach])) if reach in reference else None
        last = np.asarray(curve.get(n, []), np.float64)
        table.rows.append(
            [labels.get(encoder, encoder), scale, method, *[means.get(k) for k in range(1, n + 1)]]
            + [float(np.nanstd(last, ddof=1)) if np.isfinite(last).sum() > 1 else None, len(curve.get(1, []))]
            + [gain, se, None if target is None else (views_to_reach(means, target, sign) or f"> {n}")]
            + [step_seconds(timing.get((encoder, scale, method), {}))]
        )
    return table


def plot_active(records: Sequence[dict]):
    """IoU (top) and Chamfer (bottom) against views taken, a column per crop setting, a line per strategy
    with a +-1 standard-error band over shapes."""
    from matplotlib.figure import Figure

    scales = sorted({key[1] for key in curves(records)}, reverse=True)
    fig = Figure(figsize=(4.6 * max(len(scales), 1), 6.6))
    axes = fig.subplots(len(METRICS), max(len(scales), 1), squeeze=False)
    for row, (metric, (name, _)) in enumerate(METRICS.items()):
        data = curves(records, metric)
        for ax, scale in zip(axes[row], scales):
            for (encoder, s, method), curve in sorted(data.items()):
                if s != scale:
                    continue
                views = sorted(curve)
                mean = np.array([np.nanmean(curve[k]) for k in views])
                se = np.array([standard_error(curve[k]) for k in views])
                style = {"linestyle": ":"} if _oracle(method.partition("+")[0]) else {}
                (line,) = ax.plot(views, mean, marker="o", label=f"{encoder} {method}", **style)
                ax.fill_between(views, mean - se, mean + se, color=line.get_color(), alpha=0.15)
            ax.set(xlabel="views taken", ylabel=name, title=f"{name}, crops of area [{scale:g}, 1]")
            ax.legend(fontsize="x-small")
    fig.tight_layout()
    return fig


def _oracle(strategy: str) -> bool:
    """Whether a strategy of the records looks at the answer (False for one this tree does not know)."""
    try:
        return is_oracle(strategy)
    except ValueError:
        return False
