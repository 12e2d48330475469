"""Lightning checkpoint files: is one whole, and which one a rerun resumes from.

Checkpoints are written atomically (`ushape.atomic`), but a disk, a copy or a user can still
truncate one. A damaged checkpoint is named as such; a rerun resumes from the newest intact one
beside it, and the damaged file is renamed to `<name>.damaged` so it is never tried again.
"""

from __future__ import annotations

import logging
import pickle
import zipfile
from pathlib import Path
from typing import Any

import torch

from ushape.errors import InputError

log = logging.getLogger(__name__)

DAMAGED_SUFFIX = ".damaged"


class DamagedCheckpoint(InputError):
    """A checkpoint file that exists but cannot be loaded; the message names it and why."""


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """The checkpoint's contents; FileNotFoundError if it is missing, DamagedCheckpoint if unreadable."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=False)
    except (RuntimeError, EOFError, OSError, ValueError, pickle.UnpicklingError, zipfile.BadZipFile) as err:
        raise DamagedCheckpoint(f"checkpoint {path} is damaged ({type(err).__name__}: {err})") from err
    if not isinstance(blob, dict) or "state_dict" not in blob:
        raise DamagedCheckpoint(f"checkpoint {path} is damaged (no state_dict: not a Lightning checkpoint)")
    return blob


def _progress(blob: dict[str, Any]) -> tuple[int, int]:
    return int(blob.get("epoch", -1)), int(blob.get("global_step", -1))


def resume_point(folder: str | Path, preferred: str = "last.ckpt") -> Path | None:
    """The checkpoint a rerun continues from: `preferred` if intact, else the newest intact *.ckpt in
    `folder` (by epoch, then step); None if there is none. Damaged files are renamed aside with a warning."""
    folder = Path(folder)
    first = folder / preferred
    candidates = ([first] if first.is_file() else []) + sorted(p for p in folder.glob("*.ckpt") if p != first)
    intact: list[tuple[tuple[int, int], Path]] = []
    for path in candidates:
        try:
            blob = load_checkpoint(path)
        except DamagedCheckpoint as err:
            aside = path.with_name(path.name + DAMAGED_SUFFIX)
            path.replace(aside)
            log.warning("%s; moved it to %s", err, aside.name)
            continue
        if path == first:
            return path
        intact.append((_progress(blob), path))
    if not intact:
        return None
    newest = max(intact)[1]
    log.warning("resuming from %s, the newest intact checkpoint in %s", newest.name, folder)
    return newest
