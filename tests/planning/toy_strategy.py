"""A strategy that lives outside the package: what a new strategy needs (this module and toy_strategies/toy.yaml)."""

import numpy as np


class HighestIndex:
    """Scores each candidate by its index (ties impossible): the open candidate with the highest index, or the
    lowest with `prefer: lowest`."""

    def __init__(self, prefer: str = "highest") -> None:
        self.sign = 1.0 if prefer == "highest" else -1.0

    def scores(self, state) -> np.ndarray:  # state: ushape.planning.loop.PlanState
        return self.sign * np.arange(len(state.candidates), dtype=np.float64)
