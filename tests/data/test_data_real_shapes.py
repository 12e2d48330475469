"""The data pipeline on the real procedural generator (ushape.shapes): a tiny world per category."""

import json

import numpy as np
import pytest

shapes = pytest.importorskip("ushape.shapes")

from ushape.data.layout import WorldIndex  # noqa: E402
from ushape.data.world import SyntheticWorld  # noqa: E402


@pytest.mark.parametrize("category", shapes.CATEGORIES)
def test_tiny_real_world(category, tmp_path):
    world = SyntheticWorld(
        category,
        str(tmp_path),
        n_train=2,
        n_val=1,
        n_test=1,
        samples_per_shape=500,
        n_views=2,
        image_size=48,
        mesh_resolution=48,
    )
    index = world.build()
    assert WorldIndex.load(index.root).splits == index.splits
    for sid in index.shape_ids():
        with np.load(index.views_path(sid)) as views:
            # R2N2 framing: the object fills a good part of the image but is not cut at the border.
            coverage = views["masks"].mean(axis=(1, 2))
            assert (coverage > 0.05).all() and (coverage < 0.7).all()
            assert not views["masks"][:, [0, -1], :].any() and not views["masks"][:, :, [0, -1]].any()
        with np.load(index.sdf_path(sid)) as sdf:
            assert len(sdf["neg"]) > 20 and len(sdf["pos"]) > 20
        assert json.loads(index.shape_path(sid).read_text())["category"] == category


def test_unknown_category_lists_the_valid_ones(tmp_path):
    with pytest.raises(ValueError, match="valid categories: " + ", ".join(shapes.CATEGORIES)):
        SyntheticWorld("sofas", str(tmp_path), n_train=1, n_val=0, n_test=0)
