"""One bench row and how it is timed: the median of repeated wall-clock measurements."""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from typing import Any, Callable


@dataclass(frozen=True)
class Measurement:
    """One row: seconds (median over repeats), how it was obtained, and what it ran on."""

    name: str
    seconds: float
    repeats: int = 1
    extrapolated_from: float | None = None  # fraction of the work actually timed
    note: str = ""
    points: int | None = None  # decoder queries the row answers (grid points, vertices), for per-point costs


def timed(fn: Callable[[], Any], repeats: int, warmup: int = 0) -> tuple[float, Any]:
    """(median seconds over `repeats` calls, the last call's result)."""
    for _ in range(warmup):
        fn()
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result
