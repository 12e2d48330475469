"""Command line of bench.py.

    python bench.py                       resolution 128, decoders small and deepsdf (8 x 512)
    python bench.py --quick               resolution 32, few repeats: a smoke run (seconds)
    python bench.py --skip-slow           no MC field for any decoder
    python bench.py --decoder-dir DIR     time a trained decoder folder in place of the fitted `small`
    python bench.py --precision-only      only the mesh with uncertainty in fp32 / bf16 / auto, with the contract
    python bench.py --loaders-world DIR   also the loaders' per-core rates against a GPU's needs (a world folder)
    python bench.py --training            training against its floors (ushape.bench.training)
    python bench.py --training-contract   bf16 stage-1 training against fp32 seeds (ushape.bench.training_contract)

Untrained decoders are fitted to a procedural chair first (--fit-steps, cached), so coarse-to-fine,
the narrow band and the depth rows see one surface as with a trained decoder. The 8 x 512 decoder's
dense uncertainty fields are timed on --deepsdf-fraction of the grid points (default 1/8) and scaled
up linearly; the table marks those rows as extrapolated.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Sequence

from ushape import atomic
from ushape.bench.computation import BenchSettings, run_bench
from ushape.bench.loaders import loader_report, stage1_rate, stage2_rate
from ushape.bench.report import markdown_report
from ushape.decoder.precision import resolve_precision
from ushape.errors import InputError

DEFAULT_OUT_DIR = Path("outputs") / "bench"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description="Time the paper's computation table on this machine.")
    parser.add_argument("--quick", action="store_true", help="resolution 32, 1 repeat, 200 fusion repeats")
    parser.add_argument("--resolution", type=int, default=None, help="grid points per axis (default 128)")
    parser.add_argument("--decoders", nargs="+", default=["small", "deepsdf"], help="conf/decoder/ names")
    parser.add_argument("--decoder-dir", default=None, help="trained decoder folder used for `small`")
    parser.add_argument(
        "--repeats",
        type=int,
        default=1,
        help="repeats of each decoder-heavy row (median; the fp32 / bf16 / auto rows: interleaved rounds, minimum)",
    )
    parser.add_argument(
        "--deepsdf-fraction",
        type=float,
        default=0.125,
        help="fraction of grid points timed for deepsdf's uncertainty fields (1: all)",
    )
    parser.add_argument(
        "--precision-only",
        action="store_true",
        help="only the fp32 / bf16 / auto rows of the mesh with uncertainty (interleaved, --repeats rounds) "
        "and the precision contract",
    )
    parser.add_argument("--skip-slow", action="store_true", help="skip the Monte Carlo field rows")
    parser.add_argument(
        "--fit-steps",
        type=int,
        default=None,
        help="Adam steps fitting each untrained decoder to a procedural chair, so it has one "
        "surface as a trained decoder does (default 300; --quick 0: random weights); "
        f"cached under {DEFAULT_OUT_DIR}/fitted",
    )
    parser.add_argument("--depth-views", type=int, default=12, help="views of the depth-uncertainty rows (0: none)")
    parser.add_argument(
        "--loaders-world", default=None, help="world folder: add stage 1/2 loader throughput (ushape.bench.loaders)"
    )
    parser.add_argument(
        "--training",
        action="store_true",
        help="instead: the training bench (stage-1 step against its bare-loop and GEMM floors, the loader, latent "
        "optimisation, feature extraction; 1 and 2 threads, fp32 and bf16); with --quick a smoke run",
    )
    parser.add_argument(
        "--training-contract",
        action="store_true",
        help="instead: a fixed stage-1 run on a tiny procedural world in bf16 against 3 fp32 seeds (final loss, "
        "held-out IoU within their spread); with --quick a smoke run",
    )
    parser.add_argument("--out", default=None, help=f"report file (default {DEFAULT_OUT_DIR}/bench_<date>.md)")
    return parser


def training_main(args: argparse.Namespace) -> int:
    """`bench.py --training`: every row of ushape.bench.training, printed and written (.md and .json)."""
    from ushape.bench.training import machine, quick_settings, training_report, training_rows, write_training_report

    about = machine()
    print(f"training bench on {about['cpu']}; precision auto picks {about['auto']}")
    started = time.time()
    rows = training_rows(quick_settings()) if args.quick else training_rows()
    out = Path(args.out) if args.out else DEFAULT_OUT_DIR / f"training_{time.strftime('%Y-%m-%d')}.md"
    write_training_report(rows, about, out)
    print(training_report(rows, about) + f"\nTotal {time.time() - started:.0f} s; written to {out}")
    return 0


def contract_main(args: argparse.Namespace) -> int:
    """`bench.py --training-contract`: bf16 training against fp32 seeds, printed and written (.md and .json)."""
    import tempfile

    from ushape.bench.training import machine
    from ushape.bench.training_contract import (
        ContractSettings,
        contract_report,
        run_contract,
        write_contract_report,
    )

    about = machine()
    quick = ContractSettings(steps=20, latent_iterations=10, latent_samples=200)
    settings = quick if args.quick else ContractSettings()
    print(f"training bf16 contract on {about['cpu']}; precision auto picks {about['auto']}")
    started = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        verdict = run_contract(Path(tmp), settings)
    out = Path(args.out) if args.out else DEFAULT_OUT_DIR / f"training_contract_{time.strftime('%Y-%m-%d')}.md"
    write_contract_report(verdict, settings, about, out)
    print(contract_report(verdict, settings, about) + f"\nTotal {time.time() - started:.0f} s; written to {out}")
    return 0


def loader_section(world: str, quick: bool) -> str:
    """The paper batch's loaders timed in this process (per core) on `world`, as a markdown table."""
    one = stage1_rate(world, batches=3 if quick else 10)
    two = stage2_rate(world, batches=1 if quick else 4)
    return loader_report(one, two)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.training:
        return training_main(args)
    if args.training_contract:
        return contract_main(args)
    if args.deepsdf_fraction <= 0 or args.deepsdf_fraction > 1:
        raise InputError(f"--deepsdf-fraction must be in (0, 1], got {args.deepsdf_fraction}")
    resolution = args.resolution or (32 if args.quick else 128)
    precision, why = resolve_precision("auto")
    print(f"precision auto -> {precision}: {why}")
    settings = BenchSettings(
        precision=precision,
        precision_why=why,
        resolution=resolution,
        repeats=args.repeats,
        skip_slow=args.skip_slow,
        fusion_repeats=200 if args.quick else 2000,
        depth_views=args.depth_views,
        depth_size=16 if args.quick else 48,
        refine_views=2 if args.quick else 12,
        refine_size=16 if args.quick else 64,
        pose_azimuths=0 if args.quick else 8,  # the pose rows cost minutes on the random 8 x 512 decoder
        precision_only=args.precision_only,
    )
    fit_steps = args.fit_steps if args.fit_steps is not None else (0 if args.quick else 300)
    decoders = {name: (args.decoder_dir if name == "small" else None) for name in args.decoders}
    started = time.time()
    shared, benches = run_bench(
        settings,
        decoders,
        {"deepsdf": args.deepsdf_fraction},
        encoders=(("efficientnet_lite0", 96),) if args.quick else (("efficientnet_lite0", 96), ("resnet50", 224)),
        fit_steps=fit_steps,
        cache_dir=DEFAULT_OUT_DIR / "fitted",
    )
    report = markdown_report(shared, benches, settings)
    if args.loaders_world and not args.precision_only:
        report += "\n## Loaders: can they feed a GPU?\n\n" + loader_section(args.loaders_world, args.quick)
    report += f"\nTotal bench time {time.time() - started:.0f} s.\n"
    out = Path(args.out) if args.out else DEFAULT_OUT_DIR / f"bench_{time.strftime('%Y-%m-%d')}.md"
    atomic.write_text(out, report)
    print(report)
    print(f"written to {out}")
    return 0
