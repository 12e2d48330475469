"""Config checks made once the config is composed, before any data, folder or model is made.

A value that would only fail deep inside a run (crop.min_scale=0 at the first training batch, a
minute in; fusion.k=0 inside instantiate) is reported here with every other bad value at once.
"""

from __future__ import annotations

import numbers
from pathlib import Path
from typing import Any, Callable

from hydra.core.hydra_config import HydraConfig
from hydra.utils import get_class
from omegaconf import DictConfig, OmegaConf

from ushape.errors import InputError

STAGES = ("decoder", "encoder")


class ConfigError(InputError):
    """One or more config values that no run could use; the message lists each key and why."""


def _select(cfg: DictConfig, key: str) -> Any:
    return OmegaConf.select(cfg, key, default=None)


def _integer(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _positive_integer(value: Any) -> str | None:
    return None if _integer(value) and value >= 1 else "must be an integer >= 1"


def _count(value: Any) -> str | None:
    return None if _integer(value) and value >= 0 else "must be an integer >= 0"


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
    "data.n_train": _positive_integer,
    "data.n_val": _count,
    "data.n_test": _count,
}


def _latent_sizes(cfg: DictConfig) -> str | None:
    """The encoder predicts codes of the size the decoder takes (both given in a training config)."""
    encoder, decoder = _select(cfg, "encoder.latent_size"), _select(cfg, "decoder.latent_size")
    if encoder is None or decoder is None or encoder == decoder:
        return None
    return (
        f"encoder.latent_size={encoder!r} but decoder.latent_size={decoder!r}: the encoder predicts the "
        f"decoder's codes; leave encoder.latent_size out (it follows the decoder) or set both to one size"
    )


def _trainable_data(cfg: DictConfig) -> str | None:
    """Training needs a world with a train split; evaluation-only datasets (Pix3D) say so by EVALUATION_ONLY."""
    target = _select(cfg, "data._target_")
    if _select(cfg, "stage") is None or target is None:  # not a training config
        return None
    try:
        evaluation_only = getattr(get_class(target), "EVALUATION_ONLY", False)
    except Exception:  # a target that does not import: instantiate names it, with its own error
        return None
    if not evaluation_only:
        return None
    name = HydraConfig.get().runtime.choices.get("data") if HydraConfig.initialized() else None
    return (
        f"data={name or target} is for evaluation only (all its shapes are test shapes): train on "
        f"data=synthetic or data=shapenet, then evaluate with eval.py data={name or '<it>'}"
    )


def _data_folders(cfg: DictConfig) -> str | None:
    """The folders a dataset reads (its class's INPUT_FOLDERS) exist: a missing one would otherwise fail only
    once the world is built, after the config tree is printed."""
    target = _select(cfg, "data._target_")
    if target is None:
        return None
    try:
        keys = getattr(get_class(target), "INPUT_FOLDERS", ())
    except Exception:  # a target that does not import: instantiate names it, with its own error
        return None
    problems = []
    for key in keys:
        if OmegaConf.is_missing(cfg.data, key):
            continue  # ???: Hydra's own message says it has no value
        value = _select(cfg, f"data.{key}")
        if value not in (None, "") and not Path(str(value)).expanduser().is_dir():
            problems.append(f"data.{key}={value} is not a folder: pass the dataset's folder (data.{key}=/path/to/it)")
    return "; ".join(problems) or None


# Checks of keys together: each returns what is wrong, or None.
RELATIONS: tuple[Callable[[DictConfig], str | None], ...] = (_latent_sizes, _trainable_data, _data_folders)


def check_config(cfg: DictConfig) -> None:
    """Raise a ConfigError naming every key of `CHECKS` whose value no run could use, and every broken
    relation of `RELATIONS`."""
    problems = []
    for key, check in CHECKS.items():
        value = _select(cfg, key)
        if value is None:
            continue
        reason = check(value)
        if reason is not None:
            problems.append(f"{key}={value!r} {reason}")
    problems += [problem for relation in RELATIONS if (problem := relation(cfg)) is not None]
    if problems:
        raise ConfigError("invalid config, nothing was run: " + "; ".join(problems))
