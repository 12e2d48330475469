"""Atomic writes: all or nothing, ordinary permissions, no temporary files left behind."""

import os
import stat

import numpy as np
import pytest

from ushape import atomic


def test_write_replaces_whole_file_and_leaves_no_temporaries(tmp_path):
    target = tmp_path / "sub" / "a.npz"
    atomic.save_npz(target, pos=np.ones((3, 4), np.float32))
    atomic.save_npz(target, pos=np.zeros((5, 4), np.float32))
    assert np.load(target)["pos"].shape == (5, 4)
    assert sorted(p.name for p in target.parent.iterdir()) == ["a.npz"]
    mode = stat.S_IMODE(os.stat(target).st_mode)
    assert mode & stat.S_IRGRP and mode & stat.S_IROTH  # readable like any file, not mkstemp's 0600


def test_failure_mid_write_keeps_the_old_file(tmp_path):
    target = tmp_path / "codes.json"
    atomic.write_json(target, {"ok": 1})
    with pytest.raises(RuntimeError):
        with atomic.atomic_path(target) as tmp:
            tmp.write_text("half a fi")
            raise RuntimeError("disk full")
    assert target.read_text().strip().startswith("{") and '"ok": 1' in target.read_text()
    assert [p.name for p in tmp_path.iterdir()] == ["codes.json"]
