"""An R2N2 render folder (rendering/NN.png + rendering_metadata.txt) gives its cameras to the refinement."""

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from ushape.data.real.r2n2_world import R2N2World
from ushape.refinement.inputs import input_views, typical_r2n2_frame

_HERE = Path(os.path.dirname(os.path.abspath(__file__)))
SHARED = next((p / "shared" / "data" for p in _HERE.parents if (p / "shared" / "data").is_dir()), _HERE / "absent")
CHAIR = "1a6f615e8b1b5ae4dbbc9440457e303e"  # the shared chair with R2N2's 24 renders
RENDERS = SHARED / "real_sample" / "ShapeNetRendering"


def test_an_r2n2_render_gets_the_camera_the_world_gives_its_view(tmp_path):
    """Known answer: with the chair's own frame, the metadata row gives exactly the camera of the r2n2 world
    built from the same renders; with the world's typical frame, the same camera up to that frame's scale."""
    if not (RENDERS / "03001627" / CHAIR).is_dir():
        pytest.skip(f"shared data not present at {RENDERS}")
    split = tmp_path / "split.json"
    split.write_text(json.dumps({"train": [CHAIR], "val": [], "test": []}))
    world = R2N2World(
        "chairs",
        str(SHARED / "ShapeNetVox32"),
        str(tmp_path / "cache"),
        renderings_root=str(RENDERS),
        split_file=str(split),
        samples_per_shape=2000,
        n_views=24,
        image_size=137,
    ).build()
    folder = shutil.copytree(RENDERS / "03001627" / CHAIR / "rendering", tmp_path / "rendering")
    with np.load(world.views_path(CHAIR)) as views:
        K, w2c, frame = views["K"], views["world_to_cam"], (views["r2n2_centre"], float(views["r2n2_scale"]))
    typical = typical_r2n2_frame(world)
    np.testing.assert_allclose(typical[0], frame[0]) and np.testing.assert_allclose(typical[1], frame[1])
    images = [folder / "00.png", folder / "13.png"]
    found = input_views(images, r2n2_frame=frame)
    for view, index in zip(found, (0, 13)):
        np.testing.assert_allclose(view.K, K[index], rtol=1e-5)
        np.testing.assert_allclose(view.world_to_cam, w2c[index], rtol=1e-5, atol=1e-5)
        assert view.depth is None and view.mask.shape == (137, 137) and 0.02 < float(view.mask.mean()) < 0.6
    assert input_views(images) == [None, None]  # no frame known: no camera, said in a warning
