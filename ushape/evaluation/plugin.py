"""The interface of an evaluation protocol, and where an evaluation finds the protocols it is asked for.

A protocol is a dataclass built from conf/protocol/plugins/<name>.yaml (its `_target_` and its settings,
with `++plugins.<name>.<key>=...` on eval.py's command line, or a size preset, changing one). It owns
everything about itself:

- `run(context)` scores one encoder (see context.EvalContext: the encoder run, its encodings by crop
  scale, the reconstructor, the split's codes, and every other protocol's output, each computed once) and
  returns an `Output`: records, row lists by result key, calibration curves by space;
- `after_all` adds records measured once for the whole evaluation (Table 1's reference rows);
- `tables(result)`, `figures(result)`, `csvs(result)` and `scalars(result)` lay out what it measured,
  from the gathered result (results.json), so a report can be rebuilt from that file alone;
- `save_figures(run, ...)` saves figures that need the encoder itself.

Adding a protocol is one module with such a class and one YAML file naming it; `eval.py protocols=[...]`
takes the file's name, from conf/protocol/plugins/ or a folder listed in `protocol_dirs`. The report shows
the protocols' tables in the order they were asked for.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Mapping, Sequence

from hydra.utils import get_object
from omegaconf import OmegaConf

from ushape.builders import yaml_files
from ushape.workspace import CONFIG_DIR

PROTOCOLS_DIR = CONFIG_DIR / "protocol" / "plugins"


@dataclass
class Output:
    """What a protocol measured for one encoder: records (scored reconstructions of its own), row lists
    by result key (concatenated over encoders into results.json), and curves by space."""

    records: list[dict] = field(default_factory=list)
    rows: dict[str, list[dict]] = field(default_factory=dict)
    curves: dict[str, dict] = field(default_factory=dict)


@dataclass
class Protocol:
    """One evaluation protocol. Subclasses are dataclasses whose fields are their settings; they set
    `name` and implement `run`; the other hooks are optional."""

    name: ClassVar[str] = ""

    def run(self, context) -> Output:
        raise NotImplementedError(f"{type(self).__name__} must implement run(context) -> Output")

    def after_all(self, runs: Sequence, settings, cache_dir: Path | None) -> list[dict]:
        """Records measured once for the whole evaluation, after every encoder (none by default)."""
        return []

    def save_figures(self, run, settings, out_dir: Path) -> list[Path]:
        """Figures of one encoder saved beside the tables (none by default)."""
        return []

    def tables(self, result: dict[str, Any]) -> list:
        """Tables (evaluation.tables.Table) of this protocol, from the gathered result (none by default)."""
        return []

    def figures(self, result: dict[str, Any]) -> dict[str, Any]:
        """name -> matplotlib Figure of this protocol, from the gathered result (none by default)."""
        return {}

    def csvs(self, result: dict[str, Any]) -> dict[str, list[dict]]:
        """file stem -> rows written as <stem>.csv beside the tables (none by default)."""
        return {}

    def scalars(self, result: dict[str, Any]) -> dict[str, float]:
        """TensorBoard tag -> value of this protocol's numbers (none by default)."""
        return {}

    def config(self) -> dict[str, Any]:
        """What builds this protocol again: its `_target_` and its settings (recorded in results.json)."""
        target = f"{type(self).__module__}.{type(self).__qualname__}"
        values = {f.name: _plain(getattr(self, f.name)) for f in dataclasses.fields(self)}
        return {"_target_": target, **values}


def available(dirs: Sequence[str | Path] = ()) -> dict[str, Path]:
    """name -> YAML file of every protocol in conf/protocol/plugins/ and in dirs (a later folder wins)."""
    return yaml_files(PROTOCOLS_DIR, dirs)


def load_protocols(
    names: Sequence[str],
    overrides: Mapping[str, Mapping[str, Any]] | None = None,
    dirs: Sequence[str | Path] = (),
) -> list[Protocol]:
    """The protocols asked for, each built from its YAML file with `overrides[name]` (its settings) on top."""
    files = available(dirs)
    unknown = [n for n in names if n not in files]
    if unknown:
        raise ValueError(
            f"unknown protocols {unknown}; choose from {sorted(files)} "
            "(or add <name>.yaml to a folder listed in protocol_dirs)"
        )
    overrides = _plain(overrides or {})
    stray = sorted(set(overrides) - set(files))
    if stray:
        raise ValueError(f"plugins.{stray[0]} sets the settings of an unknown protocol; choose from {sorted(files)}")
    built = []
    for name in names:
        config = {
            **_plain(OmegaConf.to_container(OmegaConf.load(files[name]), resolve=True)),
            **overrides.get(name, {}),
        }
        built.append(build_protocol(config, str(files[name]), name))
    return built


def build_protocol(config: Mapping[str, Any], where: str, name: str | None = None) -> Protocol:
    """A protocol from its config ({_target_, settings...}); a TypeError naming `where` if it is not one."""
    values = dict(config)
    target = values.pop("_target_", None)
    cls = get_object(target) if target else None
    if not (isinstance(cls, type) and issubclass(cls, Protocol) and dataclasses.is_dataclass(cls)):
        raise TypeError(f"{where} must name (_target_) a Protocol dataclass, got {target!r}")
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise TypeError(f"{where}: {cls.__name__} has no setting {unknown[0]!r}; its settings are {sorted(known)}")
    protocol = cls(**values)
    if name is not None and protocol.name != name:
        raise TypeError(f"{where} must build a Protocol whose name is {name!r}, got {protocol.name!r}")
    return protocol


def protocols_of(result: Mapping[str, Any]) -> list[Protocol]:
    """The protocols an evaluation ran, built again from its result (results.json's `protocols`), in order."""
    return [build_protocol(config, f"results.json protocols.{name}") for name, config in result["protocols"].items()]


def _plain(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (tuple, list, range)):
        return [_plain(v) for v in value]
    return value
