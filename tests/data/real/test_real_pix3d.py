"""Pix3D on a fake tree in the official layout: annotations, filters, crops, Pix3D-MV groups, world."""

import json

import numpy as np
import pytest
import torch
from PIL import Image

from ushape.data.real.pix3d import (
    Pix3DImages,
    crop_resize,
    load_annotations,
    load_voxels,
    multiview_groups,
    square_box,
)
from ushape.data.real.pix3d_world import Pix3DWorld

W, H = 60, 40
BBOX = (20, 10, 40, 30)  # the red object in every photo


def write_photo(root, name):
    """A blue photo with a red 20x20 object at BBOX, and its mask."""
    photo = np.zeros((H, W, 3), np.uint8)
    photo[...] = (0, 0, 255)
    photo[BBOX[1] : BBOX[3], BBOX[0] : BBOX[2]] = (255, 0, 0)
    mask = np.zeros((H, W), np.uint8)
    mask[BBOX[1] : BBOX[3], BBOX[0] : BBOX[2]] = 255
    (root / "img" / "chair").mkdir(parents=True, exist_ok=True)
    (root / "mask" / "chair").mkdir(parents=True, exist_ok=True)
    Image.fromarray(photo).save(root / "img" / "chair" / f"{name}.jpg", quality=100)
    Image.fromarray(mask).save(root / "mask" / "chair" / f"{name}.png")


def entry(name, model, category="chair", **flags):
    return {
        "img": f"img/{category}/{name}.jpg",
        "mask": f"mask/{category}/{name}.png",
        "model": f"model/{category}/{model}/model.obj",
        "category": category,
        "bbox": list(BBOX),
        "img_size": [W, H],
        "rot_mat": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
        "trans_mat": [0, 0, 2],
        "focal_length": 35.0,
        "truncated": False,
        "occluded": False,
        "slightly_occluded": False,
        **flags,
    }


@pytest.fixture
def pix3d_root(tmp_path, make_box, save_obj):
    root = tmp_path / "pix3d"
    records = [entry(f"{i:04d}", "BOX_A") for i in range(23)]  # shuffled below: order must not matter
    records += [entry(f"{100 + i:04d}", "BOX_B", truncated=(i == 0)) for i in range(9)]
    records += [entry("0200", "LACK", category="table", occluded=True)]
    records = [records[i] for i in np.random.default_rng(3).permutation(len(records))]
    root.mkdir()
    (root / "pix3d.json").write_text(json.dumps(records))
    for r in records:
        if r["category"] == "chair":
            write_photo(root, r["img"].split("/")[-1][:-4])
    save_obj(root / "model" / "chair" / "BOX_A" / "model.obj", make_box())
    save_obj(root / "model" / "chair" / "BOX_B" / "model.obj", make_box(extents=(0.3, 0.3, 0.6)))
    return root


def test_annotations_and_filters(pix3d_root):
    chairs = load_annotations(pix3d_root, "chairs")
    assert len(chairs) == 32 and {e.category for e in chairs} == {"chair"}
    assert len(load_annotations(pix3d_root, "chair", drop_truncated=True)) == 31
    assert len(load_annotations(pix3d_root, "table", drop_occluded=True)) == 0
    first = next(e for e in chairs if e.img.endswith("0000.jpg"))
    assert first.model_id == "chair__BOX_A" and first.bbox == BBOX and first.img_size == (W, H)
    assert first.trans_mat == (0, 0, 2) and first.rot_mat[2] == (0, 0, 1)


def test_missing_annotations_file_explains_layout(tmp_path):
    with pytest.raises(FileNotFoundError, match="(?s)pix3d.json.*img/<category>"):
        load_annotations(tmp_path, "chair")


def test_multiview_groups_are_sorted_chunks_without_remainders(pix3d_root):
    chairs = load_annotations(pix3d_root, "chair")
    groups = multiview_groups(chairs, group_size=10)
    assert len(groups) == 2  # BOX_A: 23 -> 2 groups; BOX_B: 9 -> none
    names = [[chairs[i].img.split("/")[-1] for i in g] for g in groups]
    assert names[0] == [f"{i:04d}.jpg" for i in range(10)] and names[1][0] == "0010.jpg"
    assert len(multiview_groups(chairs, group_size=3)) == 7 + 3


def test_square_box():
    assert square_box((20, 10, 40, 30), margin=0.0) == (20, 10, 40, 30)
    assert square_box((0, 0, 40, 10), margin=0.25) == (-10, -25, 50, 35)
    with pytest.raises(ValueError, match="x1 > x0"):
        square_box((5, 5, 5, 9))


def test_gt_mask_crop_removes_background(pix3d_root):
    data = Pix3DImages(pix3d_root, "chair", image_size=16, crop_size=16, margin=0.5, mask_mode="gt_mask")
    item = data[0]
    image, mask = item["image"], item["mask"]
    assert image.shape == (3, 16, 16) and mask.shape == (1, 16, 16)
    # Object (middle half) is red; outside the mask the background is the plain white.
    np.testing.assert_allclose(image[:, 8, 8], [1, 0, 0], atol=0.05)
    np.testing.assert_allclose(image[:, 1, 1], [1, 1, 1], atol=0.05)
    assert mask[0, 8, 8] > 0.95 and mask[0, 1, 1] < 0.05


def test_no_mask_crop_keeps_the_photo(pix3d_root):
    # margin 1: the square crop spans y in [-10, 50] of the 40-pixel-high photo.
    data = Pix3DImages(pix3d_root, "chair", image_size=16, crop_size=16, margin=1.0, mask_mode="none")
    image = data[0]["image"]
    np.testing.assert_allclose(image[:, 8, 8], [1, 0, 0], atol=0.05)
    np.testing.assert_allclose(image[:, 3, 8], [0, 0, 1], atol=0.1)  # photo background above the object
    np.testing.assert_allclose(image[:, 1, 8], [1, 1, 1], atol=0.05)  # above the photo: plain fill


def test_multiview_dataset_items(pix3d_root):
    data = Pix3DImages(pix3d_root, "chair", image_size=8, crop_size=8, multiview=True)
    assert len(data) == 20 and len(data.groups) == 2
    items = [data[i] for i in (0, 9, 10)]
    assert [(x["group"], x["view"]) for x in items] == [(0, 0), (0, 9), (1, 0)]
    assert {x["model_id"] for x in items} == {"chair__BOX_A"}
    assert isinstance(items[0]["image"], torch.Tensor)


def test_pix3d_world_preprocesses_models_and_skips_broken(pix3d_root, tmp_path):
    (pix3d_root / "model" / "chair" / "BOX_B" / "model.obj").write_text("garbage\n")
    world = Pix3DWorld("chairs", str(pix3d_root), str(tmp_path / "cache"), samples_per_shape=2000)
    index = world.build()
    assert index.splits == {"train": [], "val": [], "test": ["chair__BOX_A"]}
    assert "chair__BOX_B" in json.loads((index.root / "skipped.json").read_text())
    record = json.loads(index.shape_path("chair__BOX_A").read_text())
    np.testing.assert_allclose(record["centre"], [0.1, 0.2, -0.1], atol=1e-9)
    with np.load(index.sdf_path("chair__BOX_A")) as samples:
        assert len(samples["neg"]) > 200
    assert len(world.images(multiview=True)) == 20


def test_load_voxels_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="voxel.mat"):
        load_voxels(tmp_path / "voxel.mat")


def test_large_photos_are_filtered_not_sampled_down():
    # Black and white pixel noise: each pixel of a 20 px crop covers 400 photo pixels, so it is grey
    # within a few levels (a few bilinear taps per output pixel would leave the std near 64).
    noise = ((np.random.default_rng(0).random((400, 400)) > 0.5) * 255).astype(np.uint8)
    crop = np.asarray(crop_resize(Image.fromarray(noise), (0, 0, 400, 400), 20), np.float32)
    assert crop.std() < 8 and abs(crop.mean() - 127.5) < 4
    # Outside the photo is the fill colour.
    padded = np.asarray(crop_resize(Image.fromarray(noise), (-400, 0, 400, 800), 20, fill=0), np.float32)
    assert padded[:, :8].max() == 0 and padded[:8, 12:].mean() > 100
