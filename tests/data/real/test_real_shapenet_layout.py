"""ShapeNetCore layouts, categories and splits on tiny trees written in tmp_path."""

import json

import pytest

from ushape.data.real import shapenet

CHAIRS = "03001627"


@pytest.mark.parametrize("layout", ["v1", "v2"])
def test_layout_detected_and_models_listed(shapenet_tree, layout):
    root = shapenet_tree(layout, ["b", "a", "c"])
    assert shapenet.detect_layout(root, CHAIRS) == layout
    assert shapenet.list_models(root, CHAIRS) == (layout, ["a", "b", "c"])
    assert shapenet.model_path(root, CHAIRS, "a", layout).is_file()


def test_wrong_layout_errors_name_both_patterns(tmp_path, shapenet_tree):
    with pytest.raises(FileNotFoundError, match="does not exist.*model.obj.*model_normalized.obj"):
        shapenet.detect_layout(tmp_path / "nowhere", CHAIRS)
    root = shapenet_tree("v2", ["a"])
    with pytest.raises(FileNotFoundError, match="no synset folder 04379243.*found folders \\['03001627'\\]"):
        shapenet.detect_layout(root, "04379243")
    (tmp_path / "flat" / CHAIRS / "m1").mkdir(parents=True)
    (tmp_path / "flat" / CHAIRS / "m1" / "mesh.obj").write_text("")
    with pytest.raises(ValueError, match="v1 .*model.obj.*v2 .*models/model_normalized.obj"):
        shapenet.detect_layout(tmp_path / "flat", CHAIRS)


def test_synset_ids():
    assert shapenet.synset_id("chairs") == "03001627"
    assert shapenet.synset_id("tables") == "04379243"
    assert shapenet.synset_id("02691156") == "02691156"
    with pytest.raises(ValueError, match="unknown ShapeNet category 'sofas'"):
        shapenet.synset_id("sofas")


@pytest.mark.parametrize("key", ["ShapeNetV2", "ShapeNetV1"])
def test_deepsdf_split_file_is_one_train_split(tmp_path, key):
    path = tmp_path / "chairs_train.json"
    path.write_text(json.dumps({key: {CHAIRS: ["x", "y"]}}))
    assert shapenet.read_split_source(path, CHAIRS) == {"train": ["x", "y"], "val": [], "test": []}
    with pytest.raises(ValueError, match="not 04379243"):
        shapenet.read_split_source(path, "04379243")


def test_split_formats(tmp_path):
    ours = tmp_path / "splits.json"
    ours.write_text(json.dumps({"train": ["a", "b"], "test": {"ShapeNetV2": {CHAIRS: ["c"]}}}))
    assert shapenet.read_split_source(ours, CHAIRS) == {"train": ["a", "b"], "val": [], "test": ["c"]}
    folder = tmp_path / "splits"
    folder.mkdir()
    for split, ids in {"train": ["a"], "val": ["b"], "test": ["c"]}.items():
        (folder / f"{split}.json").write_text(json.dumps(ids))
    assert shapenet.read_split_source(folder, CHAIRS) == {"train": ["a"], "val": ["b"], "test": ["c"]}
    mapping = {"train": folder / "train.json", "test": folder / "test.json"}
    assert shapenet.read_split_source(mapping, CHAIRS) == {"train": ["a"], "val": [], "test": ["c"]}
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"chairs": 3}))
    with pytest.raises(ValueError, match="unrecognised split format"):
        shapenet.read_split_source(bad, CHAIRS)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        shapenet.read_split_source(tmp_path / "missing.json", CHAIRS)


def test_hash_split_is_deterministic_and_disjoint():
    ids = [f"model{i:03d}" for i in range(100)]
    split = shapenet.hash_split(ids)
    assert split == shapenet.hash_split(list(reversed(ids)))
    assert [len(split[s]) for s in ("train", "val", "test")] == [80, 10, 10]
    assert sorted(sum(split.values(), [])) == ids
    # Hash order is stable: adding a model displaces at most one test model.
    assert len(set(split["test"]) & set(shapenet.hash_split(ids + ["extra"])["test"])) >= 9


def test_hash_split_of_three_shapes_shares_val_and_test():
    with pytest.warns(UserWarning, match="val and test share 1"):
        split = shapenet.hash_split(["a", "b", "c"])
    assert len(split["train"]) == 2 and split["val"] == split["test"] and len(split["val"]) == 1
    assert set(split["train"]) | set(split["val"]) == {"a", "b", "c"}
