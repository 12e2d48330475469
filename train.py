"""Train ushape: `python train.py loss=es category=tables` (stage 2, training stage 1 first if needed).

python train.py stage=decoder category=chairs experiment=quickstart   # stage 1 only
python train.py -m loss=es,nll,l2                                      # a sweep sharing one decoder
"""

import sys

from ushape.cli import main

if __name__ == "__main__":
    sys.exit(main(["train", *sys.argv[1:]], prog=sys.argv[0]))
