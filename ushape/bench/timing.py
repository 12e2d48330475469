"""One bench row and how it is timed: the median of repeated wall-clock measurements, or, for rows
compared with each other, the minimum of interleaved ones."""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping


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


@dataclass(frozen=True)
class Timings:
    """Seconds of each repeat of one of several interleaved computations, and its last result."""

    seconds: tuple[float, ...]
    result: Any

    @property
    def minimum(self) -> float:
        return min(self.seconds)

    @property
    def median(self) -> float:
        return statistics.median(self.seconds)


def interleaved(
    fns: Mapping[str, Callable[[], Any]], repeats: int, clock: Callable[[], float] = time.perf_counter
) -> dict[str, Timings]:
    """{name: Timings} of `repeats` rounds, each calling every fn once in turn (after one untimed call each).

    On a shared machine the load drifts; interleaving exposes every computation to the same drift, and the
    minimum over rounds is the run least disturbed by other jobs (the median says how noisy they were).
    """
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 1:
        raise ValueError(f"repeats must be a positive integer, got {repeats!r}")
    for fn in fns.values():
        fn()  # the first call pays for kernel and allocator set-up
    times: dict[str, list[float]] = {name: [] for name in fns}
    results: dict[str, Any] = {}
    for _ in range(repeats):
        for name, fn in fns.items():
            start = clock()
            results[name] = fn()
            times[name].append(clock() - start)
    return {name: Timings(tuple(times[name]), results[name]) for name in fns}
