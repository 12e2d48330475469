"""Per-shape preprocessing jobs, run in-process or over a pool of worker processes, with progress."""

from __future__ import annotations

import multiprocessing
from typing import Callable, Iterable, Iterator, Sequence, TypeVar

from tqdm.auto import tqdm

Job = TypeVar("Job")
Result = TypeVar("Result")


def run_jobs(
    fn: Callable[[Job], Result], jobs: Sequence[Job], num_workers: int, desc: str, unit: str
) -> Iterator[Result]:
    """fn over jobs, results as they finish (any order with workers); num_workers <= 0: in this process."""
    progress = dict(total=len(jobs), desc=desc, unit=unit)
    if num_workers <= 0:
        yield from tqdm(map(fn, jobs), **progress)
        return
    # spawn: workers start clean rather than inheriting the parent's thread pools mid-fork.
    with multiprocessing.get_context("spawn").Pool(num_workers) as pool:
        results: Iterable[Result] = pool.imap_unordered(fn, jobs)
        yield from tqdm(results, **progress)
