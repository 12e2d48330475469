"""The interface of an evaluation protocol, and where an evaluation finds the protocols it is asked for.

A protocol is a class built from conf/protocol/plugins/<name>.yaml (its `_target_`): `run(context)` scores one
encoder (see context.EvalContext: the encoder run, its encodings by crop scale, the reconstructor, the
split's codes, and every other protocol's output, each computed once) and returns an `Output`. Records
that several protocols share (single views at a crop, fused instances) are made through the context,
so each is scored once and lands in records.csv once. After every encoder, `after_all` may add records
(Table 1's reference rows) and `tables` lays out what the protocol alone knows how to show.

Adding a protocol is one module with such a class and one YAML file naming it; `eval.py protocols=[...]`
takes the file's name, from conf/protocol/plugins/ or a folder listed in `protocol_dirs`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from omegaconf import OmegaConf

from ushape.workspace import CONFIG_DIR

PROTOCOLS_DIR = CONFIG_DIR / "protocol" / "plugins"


@dataclass
class Output:
    """What a protocol measured for one encoder: records (scored reconstructions of its own), row lists
    by result key (concatenated over encoders into results.json), and curves by space."""

    records: list[dict] = field(default_factory=list)
    rows: dict[str, list[dict]] = field(default_factory=dict)
    curves: dict[str, dict] = field(default_factory=dict)


class Protocol:
    """One evaluation protocol. Subclasses set `name` and implement `run`; the other hooks are optional."""

    name: str = ""

    def run(self, context) -> Output:
        raise NotImplementedError(f"{type(self).__name__} must implement run(context) -> Output")

    def after_all(self, runs: Sequence, settings, cache_dir: Path | None) -> list[dict]:
        """Records measured once for the whole evaluation, after every encoder (none by default)."""
        return []

    def save_figures(self, run, settings, out_dir: Path) -> list[Path]:
        """Figures of one encoder saved beside the tables (none by default)."""
        return []

    def tables(self, result: dict[str, Any]) -> list:
        """Tables (evaluation.tables.Table) of this protocol alone, from the gathered result (none by default)."""
        return []


def available(dirs: Sequence[str | Path] = ()) -> dict[str, Path]:
    """name -> YAML file of every protocol in conf/protocol/plugins/ and in dirs (a later folder wins)."""
    found = {}
    for folder in [PROTOCOLS_DIR, *map(Path, dirs)]:
        found |= {path.stem: path for path in sorted(Path(folder).glob("*.yaml"))}
    return found


def load_protocols(names: Sequence[str], settings, dirs: Sequence[str | Path] = ()) -> list[Protocol]:
    """The protocols asked for, built from their YAML files; `${protocol.<key>}` in a file reads the size preset."""
    from hydra.utils import instantiate

    files = available(dirs)
    unknown = [n for n in names if n not in files]
    if unknown:
        raise ValueError(
            f"unknown protocols {unknown}; choose from {sorted(files)} "
            "(or add <name>.yaml to a folder listed in protocol_dirs)"
        )
    preset = OmegaConf.create({"protocol": _plain(vars(settings))})
    built = []
    for name in names:
        node = OmegaConf.merge(preset, {"this": OmegaConf.load(files[name])})
        protocol = instantiate(node.this)
        if not isinstance(protocol, Protocol) or protocol.name != name:
            raise TypeError(f"{files[name]} must build a Protocol subclass whose name is {name!r}")
        built.append(protocol)
    return built


def _plain(values: dict) -> dict:
    return {k: list(v) if isinstance(v, (tuple, range)) else v for k, v in values.items()}
