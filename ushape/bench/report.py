"""The computation table as Markdown: our timings beside the paper's A100 figures, ratios with targets."""

from __future__ import annotations

import os
import platform
from typing import Sequence

import torch

from ushape.bench.computation import BenchSettings, DecoderBench, Measurement
from ushape.bench.contract import PRECISION_ROW

# The paper's computation table (one A100, 8 x 512 DeepSDF decoder, resolution 128), seconds.
MESH_WITH_UNCERTAINTY = "mesh with uncertainty (coarse-to-fine + vertex linearised)"
MESH_WITH_UNCERTAINTY_MC = "mesh with uncertainty (coarse-to-fine + vertex mc M=10)"
PAPER_A100_S = {
    "decoder field fp32": 0.55,
    "mesh dense (field + MC)": 0.68,
    MESH_WITH_UNCERTAINTY: 0.69,
    "field uncertainty mc M=10": 5.45,
    "fusion bayesian": 0.1e-3,
}
# The computation targets (docs/benchmark.md), set so that uncertainty costs about what a plain mesh does:
# the full-grid linearised field within 2.2x the plain field (one backward costs about one forward, so 2x
# is the floor), the narrow band within 0.2x of it, depth uncertainty by
# implicit differentiation 10x faster than sphere tracing M = 10 codes.
FIELD_TARGET, BAND_TARGET, DEPTH_SPEEDUP_TARGET, REFINE_TARGET = 2.2, 0.2, 10.0, 5.0
MESH_TARGET, FUSION_TARGET_S = 1.10, 0.1e-3


def with_derived_rows(bench: DecoderBench) -> list[Measurement]:
    """The measured rows plus mesh-with-uncertainty sums (coarse-to-fine mesh + vertex std)."""
    rows = list(bench.rows)
    c2f = bench.seconds("mesh coarse-to-fine")
    for label, prefix in (
        (MESH_WITH_UNCERTAINTY, "vertex uncertainty linearised"),
        (MESH_WITH_UNCERTAINTY_MC, "vertex uncertainty mc"),
    ):
        extra = bench.seconds(prefix)
        if c2f is not None and extra is not None:
            rows.append(Measurement(label, c2f + extra, note="sum of its two rows"))
    return rows


def _paper(name: str) -> str:
    seconds = PAPER_A100_S.get(name)
    if seconds is None:
        return ""
    return f"{seconds * 1e3:.2g} ms" if seconds < 0.01 else f"{seconds:.2f} s"


def _fmt(seconds: float | None) -> str:
    if seconds is None:
        return "not run"
    if seconds < 0.01:
        return f"{seconds * 1e3:.3g} ms"
    return f"{seconds:.3g} s"


def _note(row: Measurement | None) -> str:
    if row is None:
        return ""
    parts = [row.note] if row.note else []
    if row.extrapolated_from is not None:
        parts.append(f"extrapolated from {row.extrapolated_from:.0%} of the grid points")
    return "; ".join(parts)


def _ratio(num: float | None, den: float | None) -> float | None:
    return None if num is None or den is None or den == 0 else num / den


def _total(bench: DecoderBench, *prefixes: str) -> float | None:
    """Sum of the rows starting with each prefix; None if any is missing."""
    parts = [bench.seconds(p) for p in prefixes]
    return None if any(p is None for p in parts) else sum(parts)


def ratio_rows(bench: DecoderBench) -> list[tuple[str, float | None, str, bool | None]]:
    """(ratio name, value, target text, passed or None where there is no target) for one decoder."""
    field = bench.seconds("decoder field")
    mesh = bench.seconds("mesh coarse-to-fine")
    lin = _ratio(_dense(bench, "field uncertainty linearised"), field)
    mc = _ratio(_dense(bench, "field uncertainty mc"), field)
    band_lin = _ratio(bench.seconds("field uncertainty linearised narrow band"), field)
    band_mc = _ratio(
        next(
            (
                r.seconds
                for r in bench.rows
                if r.name.startswith("field uncertainty mc") and r.name.endswith("narrow band")
            ),
            None,
        ),
        field,
    )
    depth_speedup = _ratio(bench.seconds("depth uncertainty mc"), bench.seconds("depth uncertainty implicit"))
    per_vertex = _ratio(
        _per_point(bench, "vertex uncertainty linearised"), _per_point(bench, "field uncertainty linearised")
    )
    mesh_lin = _ratio(_total(bench, "mesh coarse-to-fine", "vertex uncertainty linearised"), mesh)
    mesh_mc = _ratio(_total(bench, "mesh coarse-to-fine", "vertex uncertainty mc"), mesh)
    bf16 = next((r.seconds for r in bench.rows if r.name.startswith("decoder field") and "bf16" in r.name), None)
    refine_masks = next((r.seconds for r in bench.rows if r.name.startswith("refine masks")), None)
    refine_ratio = _ratio(refine_masks, _total(bench, "mesh coarse-to-fine", "vertex uncertainty linearised"))
    mesh32 = bench.seconds(f"{PRECISION_ROW}, fp32")
    mesh_bf16 = _ratio(bench.seconds(f"{PRECISION_ROW}, bf16"), mesh32)
    mesh_auto = _ratio(bench.seconds(f"{PRECISION_ROW}, auto"), mesh32)

    def check(value: float | None, target: float) -> bool | None:
        return None if value is None else value <= target

    return [
        ("coarse-to-fine mesh / dense mesh", _ratio(mesh, bench.seconds("mesh dense")), "(lower is better)", None),
        ("field w/ unc (linearised) / field", lin, f"<= {FIELD_TARGET:g}x", check(lin, FIELD_TARGET)),
        ("field w/ unc (MC M=10) / field", mc, "(the paper: 9.9x)", None),
        (
            "narrow-band field w/ unc (linearised) / field",
            band_lin,
            f"<= {BAND_TARGET:g}x",
            check(band_lin, BAND_TARGET),
        ),
        ("narrow-band field w/ unc (MC M=10) / field", band_mc, "(lower is better)", None),
        (
            "mesh w/ unc (linearised) / mesh, coarse-to-fine",
            mesh_lin,
            f"<= {MESH_TARGET:.2f}x",
            check(mesh_lin, MESH_TARGET),
        ),
        (
            "mesh w/ unc (MC M=10) / mesh, coarse-to-fine",
            mesh_mc,
            f"<= {MESH_TARGET:.2f}x",
            check(mesh_mc, MESH_TARGET),
        ),
        ("field bf16 / field fp32", _ratio(bf16, field), "(< 1: bf16 faster)", None),
        ("mesh w/ unc (linearised) bf16 / fp32", mesh_bf16, "(< 1: bf16 faster)", None),
        ("mesh w/ unc (linearised) auto / fp32", mesh_auto, "(1 where auto is fp32; AMX: <= 0.5)", None),
        ("vertex linearised per vertex / field linearised per point", per_vertex, "(1: at the per-point floor)", None),
        (
            "depth unc MC M=10 / implicit (speed-up)",
            depth_speedup,
            f">= {DEPTH_SPEEDUP_TARGET:g}x",
            None if depth_speedup is None else depth_speedup >= DEPTH_SPEEDUP_TARGET,
        ),
        (
            "refine masks (12 views) / mesh w/ unc (linearised)",
            refine_ratio,
            f"<= {REFINE_TARGET:g}x",
            check(refine_ratio, REFINE_TARGET),
        ),
    ]


def _per_point(bench: DecoderBench, prefix: str) -> float | None:
    """Seconds per decoder query of the first (dense) row starting with prefix, if it counted its points."""
    row = next((r for r in bench.rows if r.name.startswith(prefix) and "narrow band" not in r.name), None)
    return None if row is None or not row.points else row.seconds / row.points


def _dense(bench: DecoderBench, prefix: str) -> float | None:
    """Seconds of the dense-grid row starting with prefix (not its narrow-band sibling)."""
    return next((r.seconds for r in bench.rows if r.name.startswith(prefix) and "narrow band" not in r.name), None)


def _verdict(passed: bool | None) -> str:
    return "" if passed is None else ("pass" if passed else "miss")


def markdown_report(shared: Sequence[Measurement], benches: Sequence[DecoderBench], settings: BenchSettings) -> str:
    """The whole report: machine, per-step table (one column per decoder), ratios with pass/miss."""
    lines = [
        f"# Computation table at resolution {settings.resolution} (grids of {settings.resolution}^3; "
        "this machine vs the paper's A100)",
        "",
        f"Machine: {platform.processor() or platform.machine()}, torch {torch.__version__}, "
        f"{torch.get_num_threads()} threads, CPU only, 1-min load average {os.getloadavg()[0]:.1f} when written "
        f"(other jobs on the machine slow every row alike). Medians of {settings.repeats} run(s) per decoder row, "
        f"{settings.fusion_repeats} per fusion row; the fp32 / bf16 / auto rows: minimum of {settings.repeats} "
        "interleaved round(s).",
        "",
        f"Precision `auto` on this machine: {settings.precision} ({settings.precision_why or 'not resolved'}).",
        "",
    ]
    for bench in benches:
        lines.append(f"- decoder `{bench.name}`: {bench.parameters:,} parameters, {bench.provenance}")
    lines += [
        "",
        "| step | " + " | ".join(f"{b.name}" for b in benches) + " | paper A100 (8x512) | notes |",
        "|---|" + "---|" * len(benches) + "---|---|",
    ]
    tables = [with_derived_rows(b) for b in benches]
    names = list(dict.fromkeys(r.name for rows in tables for r in rows))
    for name in names:
        found = [next((r for r in rows if r.name == name), None) for rows in tables]
        per_decoder = {b.name: _note(r) for b, r in zip(benches, found) if _note(r)}
        if len(set(per_decoder.values())) == 1 and len(per_decoder) == len(benches):
            notes = next(iter(per_decoder.values()))
        else:
            notes = "; ".join(f"{name}: {note}" for name, note in per_decoder.items())
        cells = " | ".join(_fmt(r.seconds if r else None) for r in found)
        lines.append(f"| {name} | {cells} | {_paper(name)} | {notes} |")
    if shared:
        lines += ["", "| step (decoder-independent) | time | paper A100 | target | notes |", "|---|---|---|---|---|"]
    for row in shared:
        target, verdict = "", ""
        if row.name == "fusion bayesian":
            target, verdict = "< 0.1 ms", _verdict(row.seconds < FUSION_TARGET_S)
        lines.append(f"| {row.name} | {_fmt(row.seconds)} | {_paper(row.name)} | {target} {verdict} | {_note(row)} |")
    lines += ["", "| ratio | decoder | value | target | result |", "|---|---|---|---|---|"]
    for bench in benches:
        for name, value, target, passed in ratio_rows(bench):
            if value is None and settings.precision_only:
                continue  # the rows it divides were not run
            shown = "not run" if value is None else f"{value:.2f}x"
            lines.append(f"| {name} | {bench.name} | {shown} | {target} | {_verdict(passed)} |")
    return "\n".join(lines) + "\n"
