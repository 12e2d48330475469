"""Recorded candidates on real data: a world built from 3D-R2N2's own renders of a ShapeNet chair.

The next view of a real object is chosen among its recorded views, scored through their cameras
against the reconstructed mesh. On the real chair's own mesh, what each camera is said to see must
be where its real render shows the chair.
"""

import json
import os
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.ndimage import binary_dilation

from ushape.data.cameras import project
from ushape.data.real.shapenet_world import ShapeNetWorld
from ushape.planning.candidates import candidate_views
from ushape.planning.criteria import visible_from

REAL_SAMPLE = Path(os.path.dirname(os.path.abspath(__file__))).parents[2] / "shared" / "data" / "real_sample"
CHAIR = "1a6f615e8b1b5ae4dbbc9440457e303e"


@pytest.fixture(scope="module")
def real_world(tmp_path_factory):
    renders = REAL_SAMPLE / "ShapeNetRendering" / "03001627" / CHAIR
    if not renders.is_dir():
        pytest.skip(f"R2N2's renders of {CHAIR} not present under {REAL_SAMPLE}")
    tmp = tmp_path_factory.mktemp("r2n2")
    split = tmp / "split.json"
    split.write_text(json.dumps({"train": [CHAIR], "test": [CHAIR]}))
    world = ShapeNetWorld(
        "chairs",
        str(REAL_SAMPLE / "ShapeNetCore.v2"),
        str(tmp / "cache"),
        split_file=str(split),
        renderings_root=str(REAL_SAMPLE / "ShapeNetRendering"),
        samples_per_shape=500,
        n_views=24,
        image_size=137,
    )
    return world.build()


def test_recorded_cameras_see_the_chair_where_its_real_renders_show_it(real_world):
    candidates = candidate_views(real_world, CHAIR)  # not a synthetic world: its recorded views
    assert candidates.source == "recorded" and len(candidates) == 24
    mesh = trimesh.load(real_world.mesh_path(CHAIR), process=False, force="mesh")
    visible = visible_from(mesh, candidates.K, candidates.world_to_cam, candidates.image_hw)
    assert (visible.mean(axis=1) > 0.1).all()  # every camera sees a good part of the chair
    shift = np.eye(4)
    shift[0, 3] = 0.1  # the same camera moved 0.1 sideways: what a wrong camera convention would look like

    def inside(view, world_to_cam):
        # The chair's rods are about a pixel thin at 137 px: a vertex on one may project a pixel beside the mask.
        mask = binary_dilation(candidates.image(view)[3].numpy() > 0.5, iterations=1)
        pixels, _ = project(mesh.vertices[visible[view]], candidates.K[view], world_to_cam)
        rows, cols = np.clip(pixels[:, 1].astype(int), 0, 136), np.clip(pixels[:, 0].astype(int), 0, 136)
        return mask[rows, cols].mean()

    for view in range(len(candidates)):
        assert inside(view, candidates.world_to_cam[view]) > 0.95, view
        assert inside(view, shift @ candidates.world_to_cam[view]) < 0.9, view
