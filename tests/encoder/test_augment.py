"""Augmentations: crop areas, flips, background compositing, repeatability, bad files."""

import numpy as np
import pytest
import torch
from PIL import Image

from ushape.data.augment import (
    CompositeBackground,
    RandomHorizontalFlip,
    build_transform,
    crop_box,
    load_rgba,
    procedural_background,
    random_crop,
)


def test_load_rgba_premultiplies_and_names_bad_files(tmp_path):
    rgba = np.zeros((4, 4, 4), np.uint8)
    rgba[..., 0], rgba[:2, :, 3] = 200, 255
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    image = load_rgba(tmp_path / "a.png")
    assert image.shape == (4, 4, 4)
    assert image[0, 0, 0].item() == pytest.approx(200 / 255) and image[0, 3, 0].item() == 0.0
    (tmp_path / "bad.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match="bad.png"):
        load_rgba(tmp_path / "bad.png")
    with pytest.raises(FileNotFoundError, match="missing.png"):
        load_rgba(tmp_path / "missing.png")


def test_truncated_png_is_a_clear_error(tmp_path):
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (64, 64, 4), dtype=np.uint8), "RGBA").save(
        tmp_path / "t.png"
    )
    data = (tmp_path / "t.png").read_bytes()
    (tmp_path / "t.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="t.png"):
        load_rgba(tmp_path / "t.png")


@pytest.mark.parametrize("min_scale", [0.01, 0.1, 0.5, 1.0])
def test_crop_area_lies_in_min_scale_one(min_scale):
    g = torch.Generator().manual_seed(0)
    for _ in range(200):
        top, left, h, w = crop_box(137, 137, min_scale, (3 / 4, 4 / 3), g)
        assert 0 <= top and top + h <= 137 and 0 <= left and left + w <= 137
        area = h * w / 137**2
        assert min_scale * 0.95 <= area <= 1.0 + 1e-9  # rounding to whole pixels


def test_random_crop_is_deterministic_given_a_generator():
    image = torch.rand(4, 50, 60)
    a = random_crop(image, 0.1, torch.Generator().manual_seed(3))
    b = random_crop(image, 0.1, torch.Generator().manual_seed(3))
    assert torch.equal(a, b)
    with pytest.raises(ValueError, match="min_scale"):
        random_crop(image, 0.0)


def test_flip_mirrors_columns():
    image = torch.arange(6.0).view(1, 2, 3)
    assert torch.equal(RandomHorizontalFlip(p=1.0)(image), image.flip(-1))
    assert torch.equal(RandomHorizontalFlip(p=0.0)(image), image)


def test_gt_mask_composites_on_a_plain_background():
    rgba = torch.zeros(4, 8, 8)
    rgba[:, 2:4, 2:4] = torch.tensor([0.2, 0.4, 0.6, 1.0]).view(4, 1, 1)
    rgb = CompositeBackground("gt_mask", background_value=1.0)(rgba)
    assert torch.allclose(rgb[:, 0, 0], torch.ones(3))
    assert torch.allclose(rgb[:, 2, 2], torch.tensor([0.2, 0.4, 0.6]))


def test_random_backgrounds_vary_and_keep_the_object():
    rgba = torch.zeros(4, 16, 16)
    rgba[:, 4:8, 4:8] = torch.tensor([0.2, 0.4, 0.6, 1.0]).view(4, 1, 1)
    composite = CompositeBackground("none")
    g = torch.Generator().manual_seed(0)
    outs = [composite(rgba, g) for _ in range(10)]
    assert all(torch.allclose(o[:, 5, 5], torch.tensor([0.2, 0.4, 0.6])) for o in outs)
    assert len({round(o[:, 0, 0].sum().item(), 4) for o in outs}) > 5
    for _ in range(20):
        bg = procedural_background(12, 10, g)
        assert bg.shape == (3, 12, 10) and bg.min() >= 0 and bg.max() <= 1


def test_background_folder(tmp_path):
    Image.fromarray(np.full((40, 30, 3), 77, np.uint8)).save(tmp_path / "sun.jpg")
    rgba = torch.zeros(4, 8, 8)
    rgb = CompositeBackground("none", background_dir=tmp_path)(rgba)
    assert torch.allclose(rgb, torch.full_like(rgb, 77 / 255), atol=2e-2)
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="no .* images"):
        CompositeBackground("none", background_dir=tmp_path / "empty")


def test_unknown_mask_mode():
    with pytest.raises(ValueError, match="mask_mode"):
        CompositeBackground("seg")


def test_build_transform_train_and_eval():
    rgba = torch.rand(4, 137, 137)
    train = build_transform(32, train=True, min_scale=0.2, mask_mode="none")
    evaluate = build_transform(32, train=False)
    assert train(rgba).shape == evaluate(rgba).shape == (3, 32, 32)
    assert torch.equal(evaluate(rgba), evaluate(rgba))
    g1, g2 = torch.Generator().manual_seed(5), torch.Generator().manual_seed(5)
    assert torch.equal(train(rgba, g1), train(rgba, g2))
