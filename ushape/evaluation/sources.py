"""Which training runs an evaluation reads: given folders, a sweep's runs, or the newest run (and its sweep)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

from ushape.errors import MissingInputError
from ushape.reconstruction.pretrained import PREFIX
from ushape.workspace import MULTIRUN_DIR, RUN_SUMMARY, RUNS_DIR

SEARCHED = (RUNS_DIR, MULTIRUN_DIR)
HINT = "train one first: `python train.py experiment=quickstart` (or `-m loss=es,nll,l2` for a sweep)"


def is_encoder_run(folder: Path) -> bool:
    """A finished stage-2 run: run.json with stage == encoder."""
    summary = folder / RUN_SUMMARY
    try:
        return summary.is_file() and json.loads(summary.read_text()).get("stage") == "encoder"
    except (OSError, ValueError):
        return False


def sweep_runs(sweep: str | Path) -> list[Path]:
    """The encoder runs (job folders) of a multirun folder, in job order."""
    sweep = Path(sweep).expanduser()
    if not sweep.is_dir():
        raise MissingInputError(f"sweep folder {sweep} does not exist")
    runs = sorted((p.parent for p in sweep.glob(f"*/{RUN_SUMMARY}") if is_encoder_run(p.parent)), key=_job_order)
    if not runs:
        raise MissingInputError(f"{sweep} holds no finished encoder runs (<job>/run.json with stage=encoder): {HINT}")
    return runs


def latest_runs(root: str | Path = ".") -> list[Path]:
    """The newest encoder run under <root>/outputs/{runs,multirun}; if it is a sweep's job, all of that sweep's runs."""
    root = Path(root)
    found = [p.parent for base in SEARCHED for p in (root / base).glob(f"**/{RUN_SUMMARY}") if is_encoder_run(p.parent)]
    if not found:
        raise MissingInputError(f"no finished encoder run under {root / SEARCHED[0]} or {root / SEARCHED[1]}: {HINT}")
    newest = max(found, key=lambda p: (p / RUN_SUMMARY).stat().st_mtime)
    multirun = (root / SEARCHED[1]).resolve()
    return sweep_runs(newest.parent) if multirun in newest.resolve().parents else [newest]


def resolve_runs(
    runs: Sequence[str | Path] | None = None, sweep: str | Path | None = None, root: str | Path = "."
) -> list[Path]:
    """Run folders to evaluate: `runs` as given (each must exist), else `sweep`'s runs, else the newest."""
    if runs:
        paths = [Path(r).expanduser() for r in runs]
        # `pretrained:<name>`: a model shipped in the package (ushape.reconstruction.pretrained), not a folder
        missing = [str(p) for p in paths if not p.exists() and not str(p).startswith(PREFIX)]
        if missing:
            raise MissingInputError(f"run folder(s) {missing} do not exist: {HINT}")
        return paths
    if sweep:
        return sweep_runs(sweep)
    return latest_runs(root)


def _job_order(path: Path) -> tuple[int, str]:
    head = path.name.split("_", 1)[0]
    return (int(head), path.name) if head.isdigit() else (1 << 30, path.name)
