"""Atomic file writes: a reader sees the old file or the new one, never half of one.

Caches and checkpoints go through here, so a crash or a full disk mid-write never leaves a
truncated file that a later run would trust.
"""

from __future__ import annotations

import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ushape.errors import InputError

_UMASK = os.umask(0)
os.umask(_UMASK)


TEMP_MARK = ".tmp"  # temporary files are ".<name>.<random>.tmp<suffix>"


def is_temp_file(path: str | os.PathLike) -> bool:
    """Whether `path` is the temporary file of an atomic write (left behind if the process was killed)."""
    name = Path(path).name
    return name.startswith(".") and TEMP_MARK in name


def remove_temp_files(folder: str | os.PathLike) -> list[Path]:
    """Delete the leftover temporary files under `folder` (recursively); returns them.

    Only safe while nobody else writes there (the world build calls it under its lock).
    """
    removed = [p for p in Path(folder).rglob(f".*{TEMP_MARK}*") if p.is_file() and is_temp_file(p)]
    for path in removed:
        path.unlink(missing_ok=True)
    return removed


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success move it over `path` in one rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_MARK + path.suffix, dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    os.chmod(tmp_path, 0o666 & ~_UMASK)  # mkstemp makes 0600; a cache should read like any other file
    try:
        yield tmp_path
        with open(tmp_path, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | os.PathLike, text: str) -> None:
    write_bytes(path, text.encode("utf-8"))


def write_json(path: str | os.PathLike, obj: Any) -> None:
    write_text(path, json.dumps(obj, indent=2, sort_keys=True) + "\n")


def save_npz(path: str | os.PathLike, **arrays: np.ndarray) -> None:
    """np.savez (uncompressed) written atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)


def torch_save(obj: Any, path: str | os.PathLike) -> None:
    """torch.save written atomically."""
    import torch

    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


class DamagedFileError(InputError):
    """A stored JSON file that cannot be read back (cut off, or edited by hand); the message names it."""


def read_json_object(path: str | os.PathLike, remedy: str) -> dict[str, Any]:
    """A JSON object stored by `write_json`; a DamagedFileError naming the file and `remedy` (what to do) when it
    does not parse or is not an object."""
    path = Path(path)
    try:
        value = json.loads(path.read_text())
    except (UnicodeDecodeError, ValueError) as err:
        raise DamagedFileError(f"{path} is damaged ({err}): {remedy}") from err
    if not isinstance(value, dict):
        raise DamagedFileError(f"{path} is damaged (it holds a {type(value).__name__}, not an object): {remedy}")
    return value
