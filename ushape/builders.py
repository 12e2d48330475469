"""Objects a Hydra config describes, built with what only the run knows (paths, loggers, callbacks).

Every buildable config carries a `_target_` (conf/trainer, conf/callbacks, stage1/stage2.module,
conf/optimizer); scripts and tests may also pass plain keyword mappings, which build `default`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from hydra.utils import get_object, instantiate
from omegaconf import OmegaConf


def plain(config: Any) -> Any:
    """A config node as plain Python containers (resolved); anything else as it is."""
    return OmegaConf.to_container(config, resolve=True) if OmegaConf.is_config(config) else config


def build(config: Mapping[str, Any] | None, default: Callable[..., Any], **runtime: Any) -> Any:
    """config's `_target_` (or `default` for a plain mapping) called with config's keys and `runtime`.

    Nested configs are passed as plain dicts, not built (a module keeps its optimiser's config to build
    it over its own parameters), and run-time objects (loggers, callbacks) as they are.
    """
    kwargs = dict(plain(config) or {})
    target = get_object(kwargs.pop("_target_")) if "_target_" in kwargs else default
    return target(**kwargs, **runtime)


def yaml_files(folder: str | Path, dirs: Sequence[str | Path] = ()) -> dict[str, Path]:
    """name -> YAML file of every file in folder and in dirs, by file name (a later folder wins): where a
    plug-in (a protocol, a strategy, an observer, ...) is found by the name of its file."""
    found = {}
    for where in [folder, *map(Path, dirs)]:
        found |= {path.stem: path for path in sorted(Path(where).glob("*.yaml"))}
    return found


def build_all(configs: Mapping[str, Any] | None) -> list[Any]:
    """Every `_target_` config of a name -> config mapping (conf/callbacks), in order; null entries skipped."""
    return [instantiate(node) for node in (plain(configs) or {}).values() if node]
