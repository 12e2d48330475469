"""The paper's computation table, measured on this machine (see bench.py)."""

from ushape.bench.computation import BenchSettings, Measurement, bench_decoder, run_bench
from ushape.bench.report import markdown_report

__all__ = ["BenchSettings", "Measurement", "bench_decoder", "markdown_report", "run_bench"]
