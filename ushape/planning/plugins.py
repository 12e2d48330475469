"""Where planning finds its strategies and observers: one YAML file each, `_target_` and settings.

    conf/strategy/<name>.yaml   how the next view is chosen (uncertainty, farthest, information, oracle, ...)
    conf/observer/<name>.yaml   what the loop believes after each view (none: the fused Gaussian; masks, depth)

`active.py --strategy NAME` and the active protocol's `strategies` / `observe` take the file's name, from
these folders or from more folders given (`--strategy-dir`, the protocol's `strategy_dirs`). A class whose
objects need what only one sequence knows (its seed, the shape's own code, the observer, the predictor, the
refinement's rays and steps: `SequenceContext`) builds them with a classmethod
`for_sequence(context, **settings)`; any other class is called with the file's settings. A strategy class
may say `oracle = True` (it looks at the answer: no robot could run it) and `predicts_rows = True` (it
scores candidates by rows it predicts, which Table A-why reports).

Adding a strategy or an observer is one module with its class and one YAML file naming it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from hydra.utils import get_object
from omegaconf import OmegaConf
from torch import Tensor

from ushape.builders import yaml_files
from ushape.workspace import CONFIG_DIR

STRATEGY_DIR = CONFIG_DIR / "strategy"
OBSERVER_DIR = CONFIG_DIR / "observer"


@dataclass
class SequenceContext:
    """What a strategy or an observer may need that only its sequence knows."""

    seed: int = 0  # seeds random choices (reproducible per shape and step)
    true_code: Tensor | None = None  # [D] the shape's own code (oracles only)
    observer: Any = None  # what the loop believes after each view (oracles score that belief)
    predictor: Any = None  # the encoder's predictor (its run's fitted files)
    size: int = 24  # rays per image side of a refinement or a predicted view
    iterations: int = 15  # Levenberg-Marquardt steps at most per refinement


def strategy_names(dirs: Sequence[str | Path] = ()) -> list[str]:
    """Every strategy's name (conf/strategy/ and dirs)."""
    return list(yaml_files(STRATEGY_DIR, dirs))


def observer_names(dirs: Sequence[str | Path] = ()) -> list[str]:
    """Every observer's name (conf/observer/ and dirs)."""
    return list(yaml_files(OBSERVER_DIR, dirs))


def entry_class(kind: str, name: str, dirs: Sequence[str | Path] = ()) -> tuple[type, dict]:
    """(the class, its settings) of strategy or observer `name` (kind: "strategy" or "observer")."""
    folder = {"strategy": STRATEGY_DIR, "observer": OBSERVER_DIR}[kind]
    found = yaml_files(folder, dirs)
    if name not in found:
        raise ValueError(f"unknown {kind} {name!r}; choose one of {sorted(found)} (or add {name}.yaml to a folder)")
    config = OmegaConf.to_container(OmegaConf.load(found[name]), resolve=True)
    if not isinstance(config, dict) or "_target_" not in config:
        raise ValueError(f"{found[name]} must be a mapping with a `_target_` (the {kind}'s class)")
    return get_object(config.pop("_target_")), config


def build(kind: str, name: str, context: SequenceContext, dirs: Sequence[str | Path] = (), **settings):
    """The strategy or observer `name`, built for one sequence (`settings` on top of its file's); its `name` is
    the file's."""
    cls, own = entry_class(kind, name, dirs)
    settings = {**own, **settings}
    make = getattr(cls, "for_sequence", None)
    built = make(context, **settings) if make is not None else cls(**settings)
    built.name = name
    return built


def build_strategy(name: str, context: SequenceContext | None = None, dirs: Sequence[str | Path] = (), **settings):
    """Strategy `name` for one sequence (see the module's docstring)."""
    return build("strategy", name, context or SequenceContext(), dirs, **settings)


def build_observer(name: str, context: SequenceContext | None = None, dirs: Sequence[str | Path] = (), **settings):
    """Observer `name` for one sequence (see the module's docstring)."""
    return build("observer", name, context or SequenceContext(), dirs, **settings)


def is_oracle(name: str, dirs: Sequence[str | Path] = ()) -> bool:
    """Whether strategy `name` looks at the answer (the shape's own code)."""
    return bool(getattr(entry_class("strategy", name, dirs)[0], "oracle", False))


def predicts_rows(name: str, dirs: Sequence[str | Path] = ()) -> bool:
    """Whether strategy `name` scores candidates by the observation rows it predicts (the information ones)."""
    return bool(getattr(entry_class("strategy", name, dirs)[0], "predicts_rows", False))
