"""Print the stage-1 folder that `train.py` uses for a config (the decoder's identity hash), without training:

    python notebooks/decoder_dir.py category=chairs experiment=r2n2_cpu_2h data.voxels_root=... [overrides]

The shell recipes in notebooks/ use it to find (or restore) the folder of the run they are about to start.
"""

from __future__ import annotations

import sys

from hydra import compose, initialize_config_dir
from hydra.core.hydra_config import HydraConfig

from ushape.training.decoder_store import decoder_dir_for
from ushape.workspace import CONFIG_DIR


def main(overrides: list[str]) -> None:
    with initialize_config_dir(str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("train", overrides=overrides, return_hydra_config=True)
        HydraConfig.instance().set_config(cfg)
        print(decoder_dir_for(cfg))


if __name__ == "__main__":
    main(sys.argv[1:])
