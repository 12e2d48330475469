"""The names of what a run leaves on disk, in one place (as DeepSDF's workspace.py keeps them).

    outputs/runs/<date>/<time>_<stage>_<category>[_<loss>]/    one `python train.py` run
        run.json                 the finished run's record (stage, world, decoder, checkpoint, seconds)
        .hydra/config.yaml       the composed config
        checkpoints/best.ckpt    stage 2: the best validation epoch
        checkpoints/last.ckpt    the newest epoch, rewritten every epoch (what a resume starts from)
        temperature.json         stage 2: the variance temperature fitted on val (reconstruct.py --fit-temperature)
    outputs/multirun/<sweep>/<job>/                           the same, one folder per sweep job
"""

from __future__ import annotations

from pathlib import Path

RUNS_DIR = Path("outputs") / "runs"
MULTIRUN_DIR = Path("outputs") / "multirun"
RUN_SUMMARY = "run.json"
HYDRA_CONFIG = Path(".hydra") / "config.yaml"
CHECKPOINT_DIR = "checkpoints"
BEST_NAME = "best"
LAST_FILE = "last.ckpt"
BEST_FILE = f"{BEST_NAME}.ckpt"
TEMPERATURE_FILE = "temperature.json"
