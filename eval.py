"""Evaluate trained runs: the paper's tables (1, 3, 4, 5, S1), calibration and fusion plots.

python eval.py                                      # the newest run (all runs of its sweep)
python eval.py runs=[dir_es,dir_nll,dir_l2]         # these runs side by side
python eval.py sweep=outputs/multirun/<date>/<time> # every run of a training sweep
python eval.py -m fusion=bayesian_k fusion.k=1,2,4,10 crop.min_scale=1.0,0.1   # one row per job
python eval.py gather=outputs/multirun/<date>/<time>  # or: ushape gather <dir>
python eval.py sweep=<dir> data=pix3d data.root=/data/pix3d [category=tables]  # on Pix3D's photos
"""

import sys

from ushape.cli import main

if __name__ == "__main__":
    sys.exit(main(["eval", *sys.argv[1:]], prog=sys.argv[0]))
