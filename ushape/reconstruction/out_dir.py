"""The folder one reconstruction writes: checked before any work, held by one run at a time, and cleared of
an earlier run's outputs, so that a folder never mixes two runs' files (a 1-view summary beside the
depth maps of an earlier 3-view run)."""

from __future__ import annotations

import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from filelock import FileLock, Timeout

from ushape.errors import InputError
from ushape.workspace import LOCK_FILE, REPORT_FILE, SUMMARY_FILE

# What a reconstruction writes (pipeline, export, view_depth): removed before a new run writes its own.
OUTPUT_PATTERNS = (
    SUMMARY_FILE,
    "mesh.ply",
    "mesh.glb",
    "mesh_colourbar.png",
    "overview.png",
    "depth_*.npz",
    "depth_*.png",
    REPORT_FILE,
    "model-viewer-umd.min.js",
)


def check_out_dir(path: str | Path) -> Path:
    """`path` if a reconstruction can write there (an existing folder, or one that can be made): an InputError
    naming it otherwise. Leaves nothing behind (its write test is a temporary file, gone at once)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"--out {path} is a file, not a folder: pass a folder to write the reconstruction into")
    existing = next(p for p in (path, *path.absolute().parents) if p.exists())
    if not existing.is_dir():
        raise InputError(f"--out {path}: {existing} is a file, so the folder cannot be made there")
    try:  # a real write: os.access cannot see a read-only file system, /proc or a root-squashed share
        tempfile.TemporaryFile(dir=existing).close()
    except OSError as err:
        raise InputError(
            f"--out {path}: {existing} is not writable ({err.strerror}); pass a folder you can write to"
        ) from None
    return path


@contextmanager
def claimed(path: str | Path) -> Iterator[Path]:
    """The folder, made and held for one run: another run on it is refused (an InputError) while this one
    writes, and an earlier run's outputs are removed first."""
    path = check_out_dir(path)
    lock = FileLock(str(path / LOCK_FILE), timeout=0)
    try:
        path.mkdir(parents=True, exist_ok=True)
        lock.acquire()
    except Timeout:  # an OSError too: caught first
        raise InputError(
            f"another reconstruction is writing {path} now ({LOCK_FILE} is held): wait for it, or pass another --out"
        ) from None
    except OSError as err:  # the folder changed since check_out_dir
        raise InputError(f"--out {path} cannot be written ({err.strerror}): pass a folder you can write to") from None
    try:
        for pattern in OUTPUT_PATTERNS:  # the summary first: it must never list files that are gone
            for old in sorted(path.glob(pattern)):
                old.unlink()
        yield path
    finally:
        lock.release()
        (path / LOCK_FILE).unlink(missing_ok=True)
