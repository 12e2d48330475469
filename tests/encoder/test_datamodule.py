"""RenderDataset and EncoderDataModule on a tiny fake world."""

import json

import pytest
import torch

from ushape.data.augment import build_transform
from ushape.decoder.artifacts import CodeTable, load_codes
from ushape.encoder.datamodule import EncoderDataModule, RenderDataset


def test_items_pair_each_view_with_its_code(world, decoder_dir, world_spec):
    codes = load_codes(decoder_dir / "codes_train.pt")
    ds = RenderDataset(world, "train", codes, image_size=16)
    assert len(ds) == world_spec["splits"]["train"] * world_spec["n_views"]
    item = ds[4]
    assert item["image"].shape == (3, 16, 16) and item["image"].dtype == torch.float32
    assert item["shape_id"] == "train_1" and item["view"] == 1
    assert torch.equal(item["code"], codes.lookup("train_1"))


def test_view_subset_and_bad_views(world, decoder_dir):
    codes = load_codes(decoder_dir / "codes_val.pt")
    ds = RenderDataset(world, "val", codes, image_size=16, views=[2])
    assert [it[1] for it in ds.items] == [2, 2, 2]
    with pytest.raises(ValueError, match="out of range"):
        RenderDataset(world, "val", codes, views=[7])


def test_shapes_without_codes_are_skipped_and_none_is_an_error(world, decoder_dir):
    codes = load_codes(decoder_dir / "codes_train.pt")
    partial = CodeTable(codes.shape_ids[:2], codes.codes[:2])
    assert len(RenderDataset(world, "train", partial)) == 2 * 3
    with pytest.raises(ValueError, match="none of the"):
        RenderDataset(world, "val", codes)


def test_deterministic_items_repeat_random_transforms(world, decoder_dir):
    codes = load_codes(decoder_dir / "codes_val.pt")
    transform = build_transform(16, train=True, min_scale=0.1, mask_mode="none")
    ds = RenderDataset(world, "val", codes, transform=transform, deterministic=True, seed=3)
    assert torch.equal(ds[1]["image"], ds[1]["image"])
    assert not torch.equal(
        ds[1]["image"], RenderDataset(world, "val", codes, transform=transform, deterministic=True, seed=4)[1]["image"]
    )


def test_missing_world_pieces_say_what_to_do(world, decoder_dir, tmp_path):
    codes = load_codes(decoder_dir / "codes_train.pt")
    with pytest.raises(FileNotFoundError, match=r"splits/train.json is missing(.|\n)*SyntheticWorld"):
        RenderDataset(tmp_path / "nowhere", "train", codes)
    (world / "splits" / "train.json").write_text(json.dumps(["train_0", "ghost"]))
    ghost = CodeTable(["train_0", "ghost"], torch.zeros(2, 8))
    with pytest.raises(FileNotFoundError, match="ghost"):
        RenderDataset(world, "train", ghost)


def test_corrupt_render_is_named(world, decoder_dir):
    (world / "renders" / "val_0" / "01.png").write_bytes(b"garbage")
    ds = RenderDataset(world, "val", load_codes(decoder_dir / "codes_val.pt"))
    with pytest.raises(ValueError, match="val_0/01.png"):
        ds[1]


def test_datamodule_batches(world, decoder_dir, world_spec):
    dm = EncoderDataModule(world, decoder_dir, image_size=16, batch_size=4, min_scale=0.3, mask_mode="none")
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    assert batch["image"].shape == (4, 3, 16, 16) and batch["code"].shape == (4, world_spec["latent"])
    val_a = next(iter(dm.val_dataloader()))["image"]
    val_b = next(iter(dm.val_dataloader()))["image"]
    assert torch.equal(val_a, val_b)  # no random augmentation in validation, backgrounds repeat
    dm.setup("test")
    assert len(dm.datasets["test"]) == world_spec["splits"]["test"] * world_spec["n_views"]
