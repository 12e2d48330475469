"""Evaluate trained runs: the paper's tables (1, 3, 4, 5, S1), calibration and fusion plots.

    python eval.py                                      # the newest run (all runs of its sweep)
    python eval.py runs=[dir_es,dir_nll,dir_l2]         # these runs side by side
    python eval.py sweep=outputs/multirun/<date>/<time> # every run of a training sweep
    python eval.py -m fusion=bayesian_k fusion.k=1,2,4,10 crop.min_scale=1.0,0.1   # one row per job
    python eval.py gather=outputs/multirun/<date>/<time>  # or: python -m ushape.evaluation.gather <dir>
    python eval.py sweep=<dir> data=pix3d data.root=/data/pix3d [category=tables]  # on Pix3D's photos
"""

import ushape  # noqa: F401  (first: makes torchvision/lightning importable on CPU torch)

# isort: split

import hydra
from omegaconf import DictConfig

from ushape.evaluation.command import run_eval


@hydra.main(version_base="1.3", config_path="conf", config_name="eval")
def main(cfg: DictConfig) -> float | None:
    return run_eval(cfg)


if __name__ == "__main__":
    main()
