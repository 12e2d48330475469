"""Time the paper's computation table on this machine (see ushape.bench.cli for the options)."""

import sys

from ushape.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]], prog=sys.argv[0]))
