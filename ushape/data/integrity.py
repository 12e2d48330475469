"""Cheap checks that a cached file is whole and readable, so a truncated write is redone, not trusted.

Each check returns None when the file is fine, "missing" when it does not exist, or a short
reason when it exists but is corrupt.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import trimesh
from PIL import Image

MISSING = "missing"

# None in an expected shape matches any length along that axis.
ShapeSpec = Sequence[Optional[int]]


def check_npz(path: Path, expected: dict[str, ShapeSpec], dtypes: dict[str, str] | None = None) -> Optional[str]:
    """Problem with an npz file: missing, unreadable, lacking a key, or a wrong shape/dtype."""
    if not path.is_file():
        return MISSING
    try:
        with open(path, "rb") as fh, np.load(fh) as data:
            for key, spec in expected.items():
                if key not in data.files:
                    return f"has no array {key!r}"
                array = data[key]
                if array.ndim != len(spec) or any(s is not None and s != n for s, n in zip(spec, array.shape)):
                    return f"array {key!r} has shape {array.shape}, expected {tuple(spec)}"
                if dtypes and key in dtypes and array.dtype != np.dtype(dtypes[key]):
                    return f"array {key!r} has dtype {array.dtype}, expected {dtypes[key]}"
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
        return f"unreadable npz ({err})"
    return None


def check_png(path: Path, size_hw: tuple[int, int], mode: str = "RGBA") -> Optional[str]:
    """Problem with a PNG: missing, undecodable, or not an image of this size and mode."""
    if not path.is_file():
        return MISSING
    try:
        with open(path, "rb") as fh, Image.open(fh) as image:
            image.load()
            if image.mode != mode or image.size != (size_hw[1], size_hw[0]):
                return f"is {image.mode} {image.size[1]}x{image.size[0]}, expected {mode} {size_hw[0]}x{size_hw[1]}"
    except (OSError, ValueError, SyntaxError) as err:
        return f"undecodable png ({err})"
    return None


def check_ply(path: Path) -> Optional[str]:
    """Problem with a mesh file: missing, unparsable, or without faces."""
    if not path.is_file():
        return MISSING
    try:
        mesh = trimesh.load(path, process=False, force="mesh")
    except Exception as err:  # noqa: BLE001  (trimesh's loaders raise many exception types)
        return f"unloadable mesh ({type(err).__name__}: {err})"
    if len(mesh.faces) == 0 or not np.all(np.isfinite(mesh.vertices)):
        return "mesh has no faces or non-finite vertices"
    return None


def check_json(path: Path) -> Optional[str]:
    """Problem with a JSON file: missing or unparsable."""
    if not path.is_file():
        return MISSING
    try:
        json.loads(path.read_text())
    except (OSError, ValueError) as err:
        return f"unparsable json ({err})"
    return None


def check_text_rows(path: Path, n_rows: int, n_columns: int) -> Optional[str]:
    """Problem with a whitespace table: missing, or not n_rows rows of n_columns numbers."""
    if not path.is_file():
        return MISSING
    try:
        rows = [line.split() for line in path.read_text().splitlines() if line.strip()]
        np.array(rows, dtype=np.float64)
    except (OSError, ValueError) as err:
        return f"unparsable table ({err})"
    if len(rows) != n_rows or any(len(r) != n_columns for r in rows):
        return f"has {len(rows)} rows, expected {n_rows} rows of {n_columns} numbers"
    return None
