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

# The Hydra configs. Shipped inside the package (ushape/conf links to the checkout's top-level conf/,
# and the wheel carries the files), so an installed ushape finds them wherever it runs.
CONFIG_DIR = Path(__file__).resolve().parent / "conf"
OUTPUTS_DIR = "outputs"  # every run, decoder and data cache lives under one outputs/ folder (conf/paths)
RUNS_DIR = Path(OUTPUTS_DIR) / "runs"
MULTIRUN_DIR = Path(OUTPUTS_DIR) / "multirun"
RUN_SUMMARY = "run.json"
HYDRA_CONFIG = Path(".hydra") / "config.yaml"
CHECKPOINT_DIR = "checkpoints"
BEST_NAME = "best"
LAST_FILE = "last.ckpt"
BEST_FILE = f"{BEST_NAME}.ckpt"
TEMPERATURE_FILE = "temperature.json"


def relocated(recorded: str | Path, run_dir: Path | None) -> Path:
    """A path recorded when `run_dir` was trained, found again if outputs/ has moved since.

    Paths under outputs/ (the world, the stage-1 decoder) are looked up at the same place under the
    outputs/ folder that holds `run_dir` now; a relative one recorded against the working directory
    of the time is read against that outputs/ folder's parent. Anything else is returned as recorded.
    """
    path = Path(recorded)
    if path.is_absolute() and path.exists() or run_dir is None:
        return path
    outputs = next((p for p in (run_dir.resolve(), *run_dir.resolve().parents) if p.name == OUTPUTS_DIR), None)
    if outputs is not None and OUTPUTS_DIR in path.parts:
        tail = path.parts[len(path.parts) - path.parts[::-1].index(OUTPUTS_DIR) :]
        candidate = outputs.joinpath(*tail)
        if candidate.exists():
            return candidate
    return path
