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


_PLY_SIZES = {
    "char": 1,
    "uchar": 1,
    "int8": 1,
    "uint8": 1,
    "short": 2,
    "ushort": 2,
    "int16": 2,
    "uint16": 2,
    "int": 4,
    "uint": 4,
    "int32": 4,
    "uint32": 4,
    "float": 4,
    "float32": 4,
    "double": 8,
    "float64": 8,
}


def binary_ply_size(path: Path) -> Optional[int]:
    """File size a binary triangle-mesh PLY must have according to its header; None if not computable."""
    with open(path, "rb") as fh:
        header = fh.read(4096)
    end = header.find(b"end_header\n")
    if not header.startswith(b"ply") or end < 0:
        return None
    size, count, lines = end + len(b"end_header\n"), 0, header[:end].decode("ascii", "replace").splitlines()
    if not any(line.startswith("format binary") for line in lines):
        return None
    try:
        for words in (line.split() for line in lines):
            if words[:1] == ["element"]:
                count = int(words[2])
                if count == 0:  # an empty mesh is a problem the full load reports
                    return None
            elif words[:2] == ["property", "list"]:  # triangles: a count, then three indices
                size += count * (_PLY_SIZES[words[2]] + 3 * _PLY_SIZES[words[3]])
            elif words[:1] == ["property"]:
                size += count * _PLY_SIZES[words[1]]
    except (KeyError, IndexError, ValueError):
        return None
    return size


def check_ply(path: Path) -> Optional[str]:
    """Problem with a mesh file: missing, unparsable, or without faces."""
    if not path.is_file():
        return MISSING
    # Fast path: a binary PLY whose size matches its header is whole; loading costs ~100x more.
    if binary_ply_size(path) == path.stat().st_size and path.stat().st_size > 0:
        return None
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
