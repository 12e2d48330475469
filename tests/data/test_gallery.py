"""Gallery script: cells from shapes and from a cached world, composed into one PNG."""

import numpy as np
import pytest
from data_toy_shapes import toy_shape_factory
from PIL import Image

from ushape.data.gallery import LABEL_LINES, cells_from_shapes, cells_from_world, compose_gallery, style_label
from ushape.data.rendering import on_white
from ushape.data.world import SyntheticWorld


def test_on_white_composites_alpha():
    rgba = np.array([[[255, 0, 0, 255], [0, 0, 0, 0], [0, 0, 0, 128]]], np.uint8)
    assert on_white(rgba).tolist() == [[[255, 0, 0], [255, 255, 255], [127, 127, 127]]]


def test_style_label_is_compact_and_bounded():
    lines = style_label("chairs-1", {"legs": 4, "height": 0.4567, "size": (0.1, 0.2)}, 40)
    assert lines == ["chairs-1", "legs=4 height=0.46 size=(0.10,0.20)"]
    long = style_label("x", {f"k{i}": float(i) for i in range(60)}, 30)
    assert len(long) == LABEL_LINES and long[-1].endswith("...")


def test_gallery_from_shapes_and_world(tmp_path):
    cells = cells_from_shapes("chairs", 3, 2, 40, 32, seed=0, factory=toy_shape_factory)
    assert len(cells) == 3 and all(len(views) == 2 and views[0].shape == (40, 40, 4) for views, _ in cells)
    image = compose_gallery(cells, columns=2)
    assert image.size[0] == 2 * (2 * 40 + 8) and image.size[1] == 2 * (40 + LABEL_LINES * 12 + 8)
    pixels = np.asarray(image)
    assert (pixels < 200).any(axis=-1).mean() > 0.02  # shapes and labels drawn, not a blank page
    index = SyntheticWorld(
        "chairs",
        str(tmp_path),
        2,
        0,
        0,
        samples_per_shape=100,
        n_views=3,
        image_size=24,
        mesh_resolution=24,
        shape_factory=toy_shape_factory,
    ).build()
    world_cells = cells_from_world(index, 5, 2)
    assert len(world_cells) == 2 and world_cells[0][1][0] == index.splits["train"][0]
    out = tmp_path / "gallery.png"
    compose_gallery(world_cells, columns=2).save(out)
    assert Image.open(out).size == (2 * (2 * 24 + 8), 24 + LABEL_LINES * 12 + 8)
    with pytest.raises(ValueError, match="at least one shape"):
        compose_gallery([], columns=2)
