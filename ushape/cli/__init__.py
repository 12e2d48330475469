"""The `ushape` command: one entry point for everything ushape runs, installed with the package.

    ushape train loss=es category=tables        stage 2 (stage 1 first if needed); Hydra overrides
    ushape eval sweep=outputs/multirun/...      the paper's tables; Hydra overrides
    ushape reconstruct view.png --fusion bayesian_k
    ushape active --shape <id> --strategy uncertainty --views 6
    ushape bench --quick
    ushape view outputs/reconstructions/<time>     report.html served on localhost
    ushape gather | report | gallery | sign-bench ...

`ushape <command> --help` shows a command's options. From a source checkout the root scripts
(`python train.py`, `eval.py`, `reconstruct.py`, `active.py`, `bench.py`) run the same commands.
"""

from __future__ import annotations

import importlib
import sys
from typing import Sequence

from ushape.errors import EXIT_INTERRUPTED, reporting_bad_input

# command -> (module whose main() runs it, what it does). Hydra commands read their overrides from sys.argv.
COMMANDS: dict[str, tuple[str, str]] = {
    "train": ("ushape.cli.train", "train stage 1 and/or stage 2 (Hydra: loss=es category=tables, -m for sweeps)"),
    "eval": ("ushape.cli.eval", "evaluate trained runs: the paper's tables and plots (Hydra overrides)"),
    "reconstruct": ("ushape.reconstruction.cli", "images -> mesh with per-vertex uncertainty and depth maps"),
    "active": ("ushape.cli.active", "next-best-view: reconstruct one object view by view, each chosen by a strategy"),
    "bench": ("ushape.bench.cli", "time the paper's computation table on this machine"),
    "view": ("ushape.reconstruction.serve", "serve a reconstruction's report.html on localhost (for SSH forwarding)"),
    "gather": ("ushape.evaluation.gather", "one table from an evaluation sweep's folders"),
    "report": ("ushape.decoder.report", "a stage-1 decoder folder's reconstruction report"),
    "gallery": ("ushape.data.gallery", "a picture of the synthetic world's shapes and renders"),
    "sign-bench": ("ushape.data.real.mesh_sdf_bench", "measure real-mesh SDF signs against known answers"),
}
HYDRA_COMMANDS = ("train", "eval")


def usage() -> str:
    width = max(map(len, COMMANDS))
    lines = [f"  {name:{width}}  {about}" for name, (_, about) in COMMANDS.items()]
    return "usage: ushape <command> [options]\n\ncommands:\n" + "\n".join(lines)


def main(argv: Sequence[str] | None = None, prog: str | None = None) -> int:
    """Run `ushape <command> ...`; prog is how the user called it (a root script), for messages."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    name, rest = args[0], args[1:]
    if name not in COMMANDS:
        print(f"ushape: unknown command {name!r}\n\n{usage()}", file=sys.stderr)
        return 2
    try:
        with reporting_bad_input():  # one line and exit code 2, whichever command it comes from
            return _run(name, rest, prog)
    except KeyboardInterrupt:
        # Every file is written atomically: what was finished is kept whole, what was cut short is not written.
        # Training and evaluation resume from it; a fit or reconstruction that was cut short runs again.
        print(
            f"\ninterrupted: {prog or 'ushape ' + name} stopped; files already written are kept whole, "
            "nothing half-written; rerun the command (training and eval.py go on from what finished)",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED


def _run(name: str, rest: list[str], prog: str | None) -> int:
    command = importlib.import_module(COMMANDS[name][0]).main
    if name in HYDRA_COMMANDS:
        sys.argv = [prog or f"ushape {name}", *rest]  # Hydra parses sys.argv; a resume message repeats it
        result = command()
        return 0 if result is None or isinstance(result, float) else int(result)
    result = command(rest)
    return result if isinstance(result, int) else 0
