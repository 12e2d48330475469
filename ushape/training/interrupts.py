"""Honest ends of a stopped run: SIGTERM or Ctrl+C exit non-zero and print the command that resumes.

Lightning turns SIGTERM into a SystemExit with code 0 (`SIGTERMException`) and Ctrl+C into
`sys.exit(1)`, both without a word about resuming; a scheduler reading 0 would call a preempted
job a success. `watch_signals` records which signal came (stopping at once outside a `fit`, where
Lightning's own handler is not installed), and `resume_exit` turns the exception into the shell's
convention, 128 + signal number, after printing how to resume.
"""

from __future__ import annotations

import shlex
import signal
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Sequence


class Interrupted(BaseException):
    """Raised by `watch_signals` when a signal arrives outside Lightning's fit loop."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class SignalWatch:
    """The signal that stopped the run, once one arrived."""

    def __init__(self) -> None:
        self.signum: int | None = None

    def _on_sigterm(self, signum: int, _frame) -> None:
        self.signum = signum
        # Inside a fit, Lightning calls this from its own handler and stops after the current batch.
        if signal.getsignal(signal.SIGTERM) == self._on_sigterm:
            raise Interrupted(signum)

    def _on_sigint(self, signum: int, _frame) -> None:
        self.signum = signum
        raise KeyboardInterrupt


@contextmanager
def watch_signals() -> Iterator[SignalWatch]:
    """Record SIGTERM and SIGINT while the block runs (both still stop it); the old handlers after."""
    watch = SignalWatch()
    previous = {signal.SIGTERM: signal.getsignal(signal.SIGTERM), signal.SIGINT: signal.getsignal(signal.SIGINT)}
    signal.signal(signal.SIGTERM, watch._on_sigterm)
    signal.signal(signal.SIGINT, watch._on_sigint)
    try:
        yield watch
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def stopping_signal(err: BaseException, watch: SignalWatch) -> int | None:
    """The signal behind `err` if it is how a signal ends a run (else None: a real failure or a clean exit)."""
    from lightning.pytorch.utilities.exceptions import SIGTERMException

    if isinstance(err, Interrupted):
        return err.signum
    if isinstance(err, SIGTERMException):
        return watch.signum or signal.SIGTERM
    if isinstance(err, KeyboardInterrupt):
        return signal.SIGINT
    if isinstance(err, SystemExit) and watch.signum is not None:
        return watch.signum
    return None


def resume_command(argv: Sequence[str], run_dir: Path | None) -> str:
    """The command line that resumes: the same one, writing into the same folders, the run's own
    (`hydra.run.dir`) or, for a sweep, the sweep's (`hydra.sweep.dir`: its jobs keep their numbered
    folders, so finished ones resume from their final checkpoint instead of training again)."""
    args = list(argv)
    if run_dir is not None:
        multirun = any(a in ("-m", "--multirun") for a in args)
        key, folder = ("hydra.sweep.dir", run_dir.parent) if multirun else ("hydra.run.dir", run_dir)
        if not any(a.startswith(f"{key}=") for a in args):
            args.append(f"{key}={folder}")
    # argv[0] is a root script (python train.py ...) or the installed command (ushape train ...).
    program = ["python", args[0]] if args[0].endswith(".py") else shlex.split(args[0])
    return shlex.join([*program, *args[1:]])


def resume_exit(signum: int, command: str, kept: Sequence[str]) -> SystemExit:
    """The SystemExit (128 + signum) to raise, after telling the user what is kept and how to go on."""
    name = signal.Signals(signum).name
    lines = [f"ushape: training stopped by {name}; exit code {128 + signum}."]
    lines += [f"  kept: {item}" for item in kept]
    lines.append(f"  resume with: {command}")
    print("\n".join(lines), file=sys.stderr, flush=True)
    return SystemExit(128 + signum)
