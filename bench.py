"""Time the paper's computation table on this machine (see ushape.bench.cli for the options)."""

import sys

import ushape  # noqa: F401  (first: repairs the CPU-torch / CUDA-torchvision mismatch)

# isort: split
from ushape.bench.cli import main

if __name__ == "__main__":
    sys.exit(main())
