"""The refinement's default settings, read once from conf/refine.yaml: the one place they are declared.

RefineSettings, ObservationSettings and every caller that builds them (reconstruct.py, the evaluation's
refine methods, the active protocol's observers, the information strategies) take what they are not given
from here.
"""

from __future__ import annotations

from omegaconf import OmegaConf

from ushape.workspace import CONFIG_DIR

REFINE_FILE = CONFIG_DIR / "refine.yaml"
REFINE_DEFAULTS: dict = OmegaConf.to_container(OmegaConf.load(REFINE_FILE), resolve=True)


def with_defaults(**given) -> dict:
    """The settings given, each None (or missing) one taken from conf/refine.yaml."""
    unknown = sorted(set(given) - set(REFINE_DEFAULTS))
    if unknown:
        raise TypeError(f"unknown refinement settings {unknown}; they are {sorted(REFINE_DEFAULTS)} ({REFINE_FILE})")
    return {key: REFINE_DEFAULTS[key] if given.get(key) is None else given[key] for key in REFINE_DEFAULTS}
