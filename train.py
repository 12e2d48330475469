"""Train ushape: `python train.py loss=es category=tables` (stage 2, training stage 1 first if needed).

    python train.py stage=decoder category=chairs experiment=quickstart   # stage 1 only
    python train.py -m loss=es,nll,l2                                      # a sweep sharing one decoder
"""

import ushape  # noqa: F401  (first: makes torchvision/lightning importable on CPU torch)

# isort: split

import hydra
from omegaconf import DictConfig

from ushape.experiment.train import run


@hydra.main(version_base="1.3", config_path="conf", config_name="train")
def main(cfg: DictConfig) -> float | None:
    return run(cfg)


if __name__ == "__main__":
    main()
