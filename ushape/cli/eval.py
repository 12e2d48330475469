"""`ushape eval` / `python eval.py`: Hydra composes conf/eval.yaml and ushape.evaluation.command runs it."""

import hydra
from omegaconf import DictConfig

from ushape.training.lightning_logs import log_lightning_once
from ushape.workspace import CONFIG_DIR


@hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="eval")
def main(cfg: DictConfig) -> float | None:
    # Imported once Hydra has composed the config: an unknown option is refused without loading the models (~5 s)
    from ushape.evaluation.command import run_eval

    log_lightning_once()
    return run_eval(cfg)
