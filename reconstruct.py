"""Reconstruct a 3D shape with per-vertex uncertainty from one or more images (see ushape.reconstruction.cli).

python reconstruct.py path/to/view.png                       one view, newest quickstart run
python reconstruct.py views/ --fusion bayesian_k --k 4       a folder of views, outlier-robust fusion
python reconstruct.py --fit-temperature --run outputs/runs/<date>/<run>   then add --temperature
"""

import sys

from ushape.cli import main

if __name__ == "__main__":
    sys.exit(main(["reconstruct", *sys.argv[1:]], prog=sys.argv[0]))
