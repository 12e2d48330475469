"""`ushape eval` / `python eval.py`: Hydra composes conf/eval.yaml and ushape.evaluation.command runs it."""

import hydra
from omegaconf import DictConfig

from ushape.evaluation.command import run_eval
from ushape.workspace import CONFIG_DIR


@hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="eval")
def main(cfg: DictConfig) -> float | None:
    return run_eval(cfg)
