"""Drawing one of several named options from a numpy Generator, as a plain str for the style dict."""

from __future__ import annotations

from typing import Sequence

import numpy as np


def choose(rng: np.random.Generator, options: Sequence[str], p: Sequence[float] | None = None) -> str:
    """One of `options` (probabilities `p`, uniform if None)."""
    return str(options[rng.choice(len(options), p=p)])
