"""`ushape train` / `python train.py`: Hydra composes conf/train.yaml and ushape.training.entry runs it."""

import hydra
from omegaconf import DictConfig

from ushape.training.entry import run
from ushape.workspace import CONFIG_DIR


@hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="train")
def main(cfg: DictConfig) -> float | None:
    return run(cfg)
