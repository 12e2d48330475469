"""The guard around a training run: the config checked before anything heavy is imported, signals watched, and a
run that fails or is stopped reported in one line (how to resume, what was kept) with no empty folder left.

`python train.py` (ushape.cli.train) calls `run`. The stages themselves (`ushape.training.train`) import Lightning
and the models, ~5 s on a 2-core machine; a config that `check_config` refuses never pays it.
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

from omegaconf import DictConfig

from ushape.errors import bad_input_exit
from ushape.training.decoder_store import decoder_dir_for, legacy_decoder_dir_for
from ushape.training.interrupts import resume_command, resume_exit, stopping_signal, watch_signals
from ushape.training.lightning_logs import log_lightning_once
from ushape.training.summary import discard_if_bookkeeping_only
from ushape.training.validation import check_config
from ushape.workspace import CHECKPOINT_DIR, LAST_FILE

log = logging.getLogger(__name__)

# Set by whoever starts the processes of a distributed run: Lightning's DDP launcher (LOCAL_RANK,
# NODE_RANK, RANK) or Slurm (SLURM_PROCID). All unset or 0 in the process that writes the results.
RANK_VARIABLES = ("RANK", "LOCAL_RANK", "NODE_RANK", "SLURM_PROCID")


def is_main_process() -> bool:
    """False in the other processes of a DDP run: they train alongside, and write nothing of their own."""
    return all(os.environ.get(name, "0") == "0" for name in RANK_VARIABLES)


def run(cfg: DictConfig) -> float | None:
    """Train the configured stage(s); returns the metric a sweeper would minimise (val loss).

    Under DDP every process runs this (Lightning's launcher reruns `train.py` for ranks > 0 when the
    first `fit` starts); the other ranks join both fits and leave the folders to rank 0.
    The config is checked before any work; a run that fails leaves no folder without results, and
    one stopped by SIGTERM or Ctrl+C exits with 128 + the signal's number and prints how to resume.
    """
    main = is_main_process()
    out_dir = Path(cfg.paths.output_dir).resolve()
    with watch_signals() as watch:
        try:
            check_config(cfg)
            from ushape.training.train import train_stages  # Lightning and the models: only for a config that passed

            log_lightning_once()
            return train_stages(cfg, out_dir, main)
        except BaseException as err:
            if main and discard_if_bookkeeping_only(out_dir):
                log.info("removed %s: the run stopped before writing anything", out_dir)
            stop = bad_input_exit(err)  # a bad config or data folder: one line, not a traceback
            if stop is not None:
                raise stop from None
            signum = stopping_signal(err, watch)
            if signum is None or not main:
                raise
            raise resume_exit(signum, resume_command(sys.argv, out_dir), _kept(cfg, out_dir)) from None


def _kept(cfg: DictConfig, out_dir: Path) -> list[str]:
    """What a rerun of a stopped run starts from: the checkpoints already written."""
    decoder_dir = legacy_decoder_dir_for(cfg) or decoder_dir_for(cfg)
    found = [decoder_dir / CHECKPOINT_DIR / LAST_FILE, out_dir / CHECKPOINT_DIR / LAST_FILE]
    kept = [f"{path} (resumed from)" for path in found if path.is_file()]
    return kept or ["the data world cache (built files are reused); no checkpoint was written yet"]
