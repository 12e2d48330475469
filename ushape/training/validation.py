"""Config checks made once the config is composed, before any data, folder or model is made.

A value that would only fail deep inside a run (crop.min_scale=0 at the first training batch, a
minute in; fusion.k=0 inside instantiate) is reported here with every other bad value at once.
"""

from __future__ import annotations

import numbers
from typing import Any, Callable

from omegaconf import DictConfig, OmegaConf

STAGES = ("decoder", "encoder")


class ConfigError(ValueError):
    """One or more config values that no run could use; the message lists each key and why."""


def _select(cfg: DictConfig, key: str) -> Any:
    return OmegaConf.select(cfg, key, default=None)


def _integer(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _positive_integer(value: Any) -> str | None:
    return None if _integer(value) and value >= 1 else "must be an integer >= 1"


def _unit_interval(value: Any) -> str | None:
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and 0 < value <= 1
    return None if ok else "must be a number in (0, 1] (the smallest kept fraction of the image's area)"


def _stage(value: Any) -> str | None:
    return None if value in STAGES else f"must be one of {list(STAGES)}"


# key -> check returning a reason, or None when the value is fine; keys absent from a config are skipped.
CHECKS: dict[str, Callable[[Any], str | None]] = {
    "stage": _stage,
    "crop.min_scale": _unit_interval,
    "fusion.k": _positive_integer,
    "stage1.max_epochs": _positive_integer,
    "stage1.checkpoint_every_n_epochs": _positive_integer,
    "stage2.max_epochs": _positive_integer,
    "stage2.data.batch_size": _positive_integer,
}


def check_config(cfg: DictConfig) -> None:
    """Raise a ConfigError naming every key of `CHECKS` whose value no run could use."""
    problems = []
    for key, check in CHECKS.items():
        value = _select(cfg, key)
        if value is None:
            continue
        reason = check(value)
        if reason is not None:
            problems.append(f"{key}={value!r} {reason}")
    if problems:
        raise ConfigError("invalid config, nothing was run: " + "; ".join(problems))
