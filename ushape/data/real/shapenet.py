"""ShapeNetCore on disk: categories, the v1/v2 folder layouts, and train/val/test splits.

    v1:  <root>/<synset>/<model_id>/model.obj
    v2:  <root>/<synset>/<model_id>/models/model_normalized.obj

The layout is detected from what the synset folder holds. Splits come from a split file
(DeepSDF's per-split JSON, ushape's {"train": [...], ...}, or a folder of per-split JSON
files such as a world's splits/) or, without one, from hashing the model ids, so the same
ids always land in the same split whatever order the file system lists them in.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path
from typing import Any, Mapping, Sequence, Union

from ushape.errors import InputError, MissingInputError

SPLITS = ("train", "val", "test")
SYNSETS = {"chairs": "03001627", "tables": "04379243"}
MODEL_FILES = {"v1": Path("model.obj"), "v2": Path("models") / "model_normalized.obj"}
DEEPSDF_DATASET_KEYS = ("ShapeNetV2", "ShapeNetV1", "ShapeNetCore.v2", "ShapeNetCore.v1")
DEFAULT_FRACTIONS = (0.8, 0.1, 0.1)

SplitSource = Union[str, Path, Mapping[str, Union[str, Path]], None]

LAYOUT_HELP = (
    "Expected ShapeNetCore v1 (<root>/<synset>/<model_id>/model.obj) or "
    "v2 (<root>/<synset>/<model_id>/models/model_normalized.obj)"
)


def synset_id(category: str) -> str:
    """The 8-digit WordNet synset of a category name (chairs, tables) or of a synset id itself."""
    category = str(category).strip()
    if category in SYNSETS:
        return SYNSETS[category]
    if len(category) == 8 and category.isdigit():
        return category
    raise InputError(f"unknown ShapeNet category {category!r}: use one of {sorted(SYNSETS)} or an 8-digit synset id")


def detect_layout(root: str | Path, synset: str) -> str:
    """'v1' or 'v2', from the model files found in <root>/<synset>; a clear error if neither fits."""
    root = Path(root).expanduser()
    if not root.is_dir():
        raise MissingInputError(f"ShapeNet root {root} does not exist. {LAYOUT_HELP}.")
    folder = root / synset
    if not folder.is_dir():
        found = sorted(p.name for p in root.iterdir() if p.is_dir())[:8]
        raise MissingInputError(
            f"{root} has no synset folder {synset}. {LAYOUT_HELP}; found folders {found}. "
            "Point data.root at the folder that holds the synset folders."
        )
    counts = {name: sum(1 for d in folder.iterdir() if (d / rel).is_file()) for name, rel in MODEL_FILES.items()}
    if counts["v1"] == counts["v2"] == 0:
        raise InputError(f"no model files under {folder}. {LAYOUT_HELP}.")
    if counts["v1"] and counts["v2"]:
        warnings.warn(f"{folder} mixes v1 and v2 model files ({counts}); using the more common layout")
    return "v2" if counts["v2"] >= counts["v1"] else "v1"


def model_path(root: str | Path, synset: str, model_id: str, layout: str) -> Path:
    """Path of one model's OBJ file in the given layout."""
    if layout not in MODEL_FILES:
        raise InputError(f"layout must be one of {sorted(MODEL_FILES)}, got {layout!r}")
    return Path(root).expanduser() / synset / model_id / MODEL_FILES[layout]


def list_models(root: str | Path, synset: str) -> tuple[str, list[str]]:
    """(layout, sorted ids of the models that have a model file in that layout)."""
    layout = detect_layout(root, synset)
    folder = Path(root).expanduser() / synset
    ids = sorted(d.name for d in folder.iterdir() if (d / MODEL_FILES[layout]).is_file())
    return layout, ids


def read_split_source(source: SplitSource, synset: str) -> dict[str, list[str]]:
    """{"train": ids, "val": ids, "test": ids} from a split file, a folder of them, or {split: file}.

    A single DeepSDF file ({"ShapeNetV2": {synset: [ids]}}) is one split: it becomes train.
    """
    if source is None:
        raise InputError("no split source given; use hash_split for a split without a file")
    if isinstance(source, Mapping):
        unknown = set(source) - set(SPLITS)
        if unknown:
            raise InputError(f"split files given for unknown splits {sorted(unknown)}; use {SPLITS}")
        return {s: _ids_of(_read_json(Path(source[s])), synset, Path(source[s])) if s in source else [] for s in SPLITS}
    path = Path(source).expanduser()
    if path.is_dir():
        files = {s: path / f"{s}.json" for s in SPLITS if (path / f"{s}.json").is_file()}
        if "train" not in files:
            raise MissingInputError(f"split folder {path} has no train.json (expected train/val/test.json)")
        return read_split_source(files, synset)
    data = _read_json(path)
    if isinstance(data, dict) and set(data) & set(SPLITS):
        return {s: _ids_of(data.get(s, []), synset, path) for s in SPLITS}
    return {"train": _ids_of(data, synset, path), "val": [], "test": []}


def _read_json(path: Path) -> Any:
    if not path.is_file():
        raise MissingInputError(f"split file {path} does not exist")
    try:
        return json.loads(path.read_text())
    except ValueError as err:
        raise InputError(f"split file {path} is not valid JSON ({err})") from err


def _ids_of(data: Any, synset: str, path: Path) -> list[str]:
    """Model ids of one split: a plain JSON list, or DeepSDF's {dataset: {synset: [ids]}}."""
    if isinstance(data, list) and all(isinstance(i, str) for i in data):
        return list(data)
    if isinstance(data, dict):
        for key in DEEPSDF_DATASET_KEYS:
            if key in data:
                by_synset = data[key]
                if synset not in by_synset:
                    raise InputError(f"{path}: {key} lists synsets {sorted(by_synset)}, not {synset}")
                return [str(i) for i in by_synset[synset]]
    raise InputError(
        f"{path}: unrecognised split format. Expected a JSON list of ids, DeepSDF's "
        f'{{"ShapeNetV2": {{"{synset}": [ids]}}}}, or {{"train": [...], "val": [...], "test": [...]}}'
    )


def id_hash(model_id: str) -> int:
    """A stable 64-bit hash of a model id (Python's hash() changes between runs)."""
    return int.from_bytes(hashlib.sha256(model_id.encode()).digest()[:8], "big")


def hash_split(ids: Sequence[str], fractions: Sequence[float] = DEFAULT_FRACTIONS) -> dict[str, list[str]]:
    """Deterministic train/val/test split of ids by hash, with val and test sized by `fractions`.

    Every non-zero held-out fraction gets at least one shape. When that would leave train
    smaller than the held-out sets (fewer than ~4 shapes), val and test share their shapes
    (with a warning) so train keeps the rest.
    """
    if len(fractions) != 3 or any(f < 0 for f in fractions) or fractions[0] <= 0:
        raise InputError(f"fractions must be (train > 0, val >= 0, test >= 0), got {tuple(fractions)}")
    ordered = sorted(dict.fromkeys(ids), key=lambda i: (id_hash(i), i))
    n = len(ordered)
    if n == 0:
        raise InputError("cannot split an empty list of model ids")
    total = float(sum(fractions))
    n_val, n_test = (max(1, round(n * f / total)) if f > 0 else 0 for f in fractions[1:])
    if n == 1:
        warnings.warn("only one shape: it goes to train and val/test stay empty")
        return {"train": ordered, "val": [], "test": []}
    if n - n_val - n_test < n_val + n_test:
        shared = max(n_val, n_test)
        warnings.warn(f"only {n} shapes: val and test share {shared} shape(s) so train keeps {n - shared}")
        held = ordered[:shared]
        return {"train": ordered[shared:], "val": held if n_val else [], "test": held if n_test else []}
    return {"train": ordered[n_test + n_val :], "val": ordered[n_test : n_test + n_val], "test": ordered[:n_test]}
