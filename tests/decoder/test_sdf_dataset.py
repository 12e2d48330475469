"""SDF sample loading: DeepSDF's half-positive/half-negative draws and helpful errors."""

import numpy as np
import pytest
import torch

from ushape import atomic
from ushape.data.layout import read_split
from ushape.data.sdf_dataset import SDFSamplesDataset
from ushape.decoder.datamodule import SDFDataModule


def test_items_draw_half_outside_half_inside(sphere_world):
    data = SDFSamplesDataset(sphere_world, "train", samples_per_shape=1000)
    assert data.shape_ids == ["r30", "r40", "r50", "r60"]
    item = data[2]
    assert item["index"] == 2 and item["xyz"].shape == (1000, 3) and item["sdf"].shape == (1000,)
    assert (item["sdf"] >= 0).sum() == 500 and (item["sdf"] < 0).sum() == 500
    # The samples are of the radius-0.5 sphere: sdf = |x| - 0.5 exactly.
    assert torch.allclose(item["sdf"], item["xyz"].norm(dim=1) - 0.5, atol=1e-5)
    assert not torch.equal(data[2]["xyz"], item["xyz"])  # a fresh draw each time


def test_missing_split_names_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="splits/train.json"):
        read_split(tmp_path, "train")


def test_corrupt_npz_names_the_file_and_says_rebuild(tmp_path):
    atomic.write_json(tmp_path / "splits" / "train.json", ["bad", "nokeys"])
    atomic.write_bytes(tmp_path / "sdf" / "bad.npz", b"not a zip file")
    atomic.save_npz(tmp_path / "sdf" / "nokeys.npz", pos=np.zeros((3, 4), np.float32))
    data = SDFSamplesDataset(tmp_path, "train", samples_per_shape=10)
    with pytest.raises(ValueError, match=r"bad\.npz.*rebuild"):
        data[0]
    with pytest.raises(ValueError, match=r"nokeys\.npz.*rebuild"):
        data[1]


def test_missing_npz_is_file_not_found(tmp_path):
    atomic.write_json(tmp_path / "splits" / "val.json", ["ghost"])
    with pytest.raises(FileNotFoundError, match=r"ghost\.npz"):
        SDFSamplesDataset(tmp_path, "val", samples_per_shape=10)[0]


def test_datamodule_batches_and_validation_references(sphere_world):
    dm = SDFDataModule(sphere_world, samples_per_shape=64, shapes_per_batch=3, val_num_shapes=2)
    batches = list(dm.train_dataloader())
    assert len(batches) == 1  # 4 shapes, batches of 3, last partial batch dropped as in DeepSDF
    assert batches[0]["xyz"].shape == (3, 64, 3) and batches[0]["sdf"].shape == (3, 64)
    refs = list(dm.val_dataloader())
    assert [r["index"] for r in refs] == [0, 3]
    assert refs[1]["mesh_path"].endswith("meshes/r60.ply")
