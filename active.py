"""Active reconstruction of one object: each next view chosen by a strategy (see ushape.cli.active).

python active.py                                          newest run, first test shape, uncertainty-guided
python active.py --shape <id> --strategy farthest --views 8 --min-scale 0.1
"""

import sys

from ushape.cli import main

if __name__ == "__main__":
    sys.exit(main(["active", *sys.argv[1:]], prog=sys.argv[0]))
