"""SyntheticWorld: layout, idempotence, corrupt-file recovery, deterministic disjoint splits, clear errors."""

import json
import os

import numpy as np
import pytest
from data_toy_shapes import toy_shape_factory
from PIL import Image

from ushape.data.cameras import metadata_to_cameras, parse_metadata
from ushape.data.layout import SPLITS, WorldIndex
from ushape.data.world import SyntheticWorld, shape_seeds

TINY = dict(n_train=3, n_val=1, n_test=1, samples_per_shape=400, n_views=4, image_size=32, mesh_resolution=40)


def tiny_world(root, **overrides):
    return SyntheticWorld("chairs", str(root), **{**TINY, **overrides}, shape_factory=toy_shape_factory)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    world = tiny_world(tmp_path_factory.mktemp("worlds"))
    return world, world.build()


def _all_files(root):
    return {p: p.stat().st_mtime_ns for p in root.rglob("*") if p.is_file()}


def test_layout_matches_the_documented_one(built):
    world, index = built
    assert index.root == world.directory and index.root.name == f"chairs-{world.config_hash}"
    assert len(world.config_hash) == 12
    assert json.loads((index.root / "config.json").read_text()) == world.config
    assert [len(index.splits[s]) for s in SPLITS] == [3, 1, 1]
    for sid in index.shape_ids():
        with np.load(index.sdf_path(sid)) as sdf:
            assert sdf["pos"].shape[1] == sdf["neg"].shape[1] == 4
            assert len(sdf["pos"]) + len(sdf["neg"]) == 400
            assert (sdf["pos"][:, 3] >= 0).all() and (sdf["neg"][:, 3] < 0).all()
        record = json.loads(index.shape_path(sid).read_text())
        assert record["shape_id"] == sid and isinstance(record["seed"], int) and "radius" in record["style"]
        assert index.mesh_path(sid).is_file()
        assert [p.name for p in index.image_paths(sid)] == ["00.png", "01.png", "02.png", "03.png"]


def test_views_agree_with_images_and_metadata(built):
    _, index = built
    sid = index.splits["val"][0]
    with np.load(index.views_path(sid)) as views:
        K, w2c, masks, depth = views["K"], views["world_to_cam"], views["masks"], views["depth"]
        centre, scale = views["r2n2_centre"], float(views["r2n2_scale"])
    assert K.shape == (4, 3, 3) and w2c.shape == (4, 4, 4) and masks.shape == depth.shape == (4, 32, 32)
    for view, path in enumerate(index.image_paths(sid)):
        rgba = np.asarray(Image.open(path))
        assert rgba.shape == (32, 32, 4)
        assert np.array_equal(rgba[..., 3] > 0, masks[view]) and masks[view].sum() > 20
        assert (rgba[~masks[view]] == 0).all() and (depth[view][~masks[view]] == 0).all()
    rows = parse_metadata(index.metadata_path(sid).read_text())
    K2, w2c2 = metadata_to_cameras(rows, 32, r2n2_centre=centre, r2n2_scale=scale)
    assert np.allclose(K2, K, atol=1e-4) and np.allclose(w2c2, w2c, atol=1e-5)


def test_second_build_regenerates_nothing(built):
    world, index = built
    before = _all_files(index.root)
    again = world.build()
    assert world.last_build == {}
    assert _all_files(index.root) == before
    assert again.splits == index.splits


def test_corrupt_files_are_regenerated_with_a_warning(tmp_path):
    world = tiny_world(tmp_path)
    index = world.build()
    sid = index.splits["train"][1]
    good_sdf = index.sdf_path(sid).read_bytes()
    index.sdf_path(sid).write_bytes(good_sdf[: len(good_sdf) // 2])
    png = index.image_paths(sid)[2]
    png.write_bytes(png.read_bytes()[:40])
    os.remove(index.mesh_path(index.splits["test"][0]))  # missing: regenerated silently
    ply = index.mesh_path(index.splits["val"][0])
    ply.write_bytes(ply.read_bytes()[:-7])
    with pytest.warns(UserWarning, match="corrupt cache file") as record:
        world.build()
    assert len(record) == 3, [str(r.message) for r in record]
    assert world.last_build == {"sdf": 1, "renders": 1, "mesh": 2}
    assert index.sdf_path(sid).read_bytes() == good_sdf  # same seed stream: identical samples
    assert np.asarray(Image.open(png)).shape == (32, 32, 4)
    (index.root / "splits" / "val.json").write_text("[not json")
    with pytest.warns(UserWarning, match="val.json"):
        assert world.build().splits == index.splits


def test_splits_are_deterministic_and_disjoint(built, tmp_path):
    _, index = built
    assert tiny_world(tmp_path / "other").build().splits == index.splits
    seeds = shape_seeds(0, {"train": 300, "val": 25, "test": 25})
    assert seeds == shape_seeds(0, {"train": 300, "val": 25, "test": 25})
    flat = [s for split in SPLITS for s in seeds[split]]
    assert len(set(flat)) == len(flat) == 350
    assert shape_seeds(1, {"train": 5, "val": 0, "test": 0})["train"] != seeds["train"][:5]
    assert shape_seeds(0, {"train": 5, "val": 0, "test": 0})["train"] == seeds["train"][:5]


def test_config_changes_make_a_new_world(tmp_path):
    a, b = tiny_world(tmp_path), tiny_world(tmp_path, n_views=5)
    assert a.directory != b.directory and a.directory.parent == b.directory.parent


def test_bad_root_gives_a_clear_error(built, tmp_path):
    with pytest.raises(FileNotFoundError, match="(?s)does not exist.*Expected a folder"):
        WorldIndex.load(tmp_path / "nowhere")
    _, index = built
    with pytest.raises(FileNotFoundError, match=f"(?s)holds the world folders.*{index.root.name}"):
        WorldIndex.load(index.root.parent)
    (tmp_path / "config.json").write_text('{"category": "chairs"}')
    with pytest.raises(ValueError, match="lacks the keys"):
        WorldIndex.load(tmp_path)


def test_bad_parameters_are_rejected(tmp_path):
    with pytest.raises(ValueError, match="n_train >= 1"):
        tiny_world(tmp_path, n_train=0)
    with pytest.raises(ValueError, match="n_views must be positive"):
        tiny_world(tmp_path, n_views=0)


def test_worker_processes_build_the_same_world(built, tmp_path):
    _, index = built
    parallel = tiny_world(tmp_path, num_workers=2).build()
    assert parallel.splits == index.splits
    # Byte for byte: a worker runs the same per-shape job (numpy, no torch) on the same seeds, with the same
    # libraries and thread settings, as this process.
    for sid in index.shape_ids():
        assert parallel.sdf_path(sid).read_bytes() == index.sdf_path(sid).read_bytes()
        assert parallel.image_paths(sid)[0].read_bytes() == index.image_paths(sid)[0].read_bytes()
