"""Fault injection on a cached world: leftover temp files, damaged files seen by any command, racing builders."""

import multiprocessing as mp
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from data_toy_shapes import toy_shape_factory

from ushape.data.world import SyntheticWorld, open_world
from ushape.encoder.datamodule import view_files

TINY = dict(n_train=2, n_val=1, n_test=1, samples_per_shape=200, n_views=3, image_size=24, mesh_resolution=32)


def tiny_world(root):
    return SyntheticWorld("chairs", str(root), **TINY, shape_factory=toy_shape_factory)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    world = tiny_world(tmp_path_factory.mktemp("world_faults"))
    return world, world.build()


def _files(root):
    return {p: p.read_bytes() for p in root.rglob("*") if p.is_file()}


def test_temp_files_of_interrupted_writes_are_no_views_and_are_cleaned(built):
    """view_files globbed *.png, which matches '.01.png.x.tmp.png': a killed write added a view."""
    world, index = built
    sid = index.shape_ids("train")[0]
    leftover = index.render_dir(sid) / ".01.png.k3j2.tmp.png"
    leftover.write_bytes(index.image_paths(sid)[1].read_bytes()[:50])  # half a PNG, as a kill leaves it
    assert view_files(index.root, sid) == index.image_paths(sid)
    before = {p: b for p, b in _files(index.root).items() if p != leftover}
    world.build()
    assert not leftover.exists()
    assert _files(index.root) == before  # nothing already computed was redone or lost


@pytest.mark.parametrize("damage", ["garbage_ply", "truncated_npz", "deleted_render", "truncated_render"])
def test_every_command_opening_a_world_repairs_it_and_names_the_file(tmp_path, damage):
    """eval.py used to open the world without checking it: raw tracebacks, two not naming the file."""
    index = tiny_world(tmp_path).build()
    sid = index.shape_ids("test")[0]
    intact = _files(index.root)
    path = {
        "garbage_ply": index.mesh_path(sid),
        "truncated_npz": index.sdf_path(sid),
        "deleted_render": index.image_paths(sid)[2],
        "truncated_render": index.image_paths(sid)[0],
    }[damage]
    if damage == "garbage_ply":
        path.write_bytes(b"ply\nformat ascii 1.0\nthis is not a mesh\n")
    elif damage == "deleted_render":
        os.remove(path)
    else:
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    if damage == "deleted_render":
        opened = open_world(index.root)  # a missing file is regenerated without a warning
    else:
        with pytest.warns(UserWarning, match=f"corrupt cache file {path}"):
            opened = open_world(index.root)
    assert opened.root == index.root
    repaired = _files(index.root)
    assert repaired.keys() == intact.keys()
    # Same seeds: the regenerated samples are the very same; nothing else was touched.
    changed = {p for p in intact if repaired[p] != intact[p]}
    assert changed <= {index.mesh_path(sid)} | set(index.image_paths(sid))
    assert repaired[index.sdf_path(sid)] == intact[index.sdf_path(sid)]


def _build_and_report(root, queue):
    world = tiny_world(root)
    world.build()
    queue.put(dict(world.last_build))


def test_two_jobs_racing_for_one_world_build_it_once(tmp_path):
    """Without a lock both jobs generated every shape (consistent, but twice the work)."""
    context = mp.get_context("fork")
    queue = context.Queue()
    jobs = [context.Process(target=_build_and_report, args=(tmp_path, queue)) for _ in range(2)]
    for job in jobs:
        job.start()
    for job in jobs:
        job.join(timeout=300)
    made = sorted((queue.get(timeout=5) for _ in jobs), key=len)
    assert made[0] == {}  # the job that waited found the world finished
    assert made[1]["shape"] == sum(TINY[k] for k in ("n_train", "n_val", "n_test"))
    assert np.all([job.exitcode == 0 for job in jobs])


def test_a_read_only_world_is_checked_and_its_damage_named(tmp_path, monkeypatch):
    """Shared data that this user cannot write: named, not repaired (no lock file can be made beside it)."""
    index = tiny_world(tmp_path / "shared").build()
    sdf = index.sdf_path(index.shape_ids("val")[0])
    sdf.write_bytes(sdf.read_bytes()[:100])
    monkeypatch.setattr("ushape.data.world.os.access", lambda path, mode: False)  # as a non-owner sees it
    with pytest.raises(ValueError, match=f"read-only world .* {sdf} .*keeping its name {index.root.name}"):
        open_world(index.root)
    assert sdf.stat().st_size == 100  # untouched
    monkeypatch.undo()
    # The advice works: a copy under the same name, in a writable folder, is repaired there.
    copy = Path(shutil.copytree(index.root, tmp_path / "mine" / index.root.name))
    assert open_world(copy).sdf_path(index.shape_ids("val")[0]).stat().st_size > 100
