"""Shared test set-up: ushape first (it makes torchvision importable), CPU, small thread pools."""

import os

os.environ.setdefault("OMP_NUM_THREADS", "2")

import ushape  # noqa: E402,F401  (must precede torchvision/lightning imports)

# isort: split
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(2)


@pytest.fixture(autouse=True)
def _seed():
    torch.manual_seed(0)
    np.random.seed(0)
