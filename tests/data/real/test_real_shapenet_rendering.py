"""R2N2's real renders of a ShapeNet chair against its mesh through ushape's cameras.

The renders and metadata are 3D-R2N2's own files (ShapeNetRendering), so unlike a fake tree
rendered with ushape's cameras they can catch a camera convention error: every view's alpha
mask must overlap our render of the real mesh through the camera built from its metadata row.
"""

import json

import numpy as np
import pytest

from ushape.data.cameras import FRAME_FROM_V1
from ushape.data.real import shapenet_rendering
from ushape.data.real.mesh_sdf import load_mesh, normalise_mesh
from ushape.data.real.shapenet_world import ShapeNetWorld
from ushape.data.rendering import render_views

CHAIRS = "03001627"
CHAIR = "1a6f615e8b1b5ae4dbbc9440457e303e"
MIN_VIEW_IOU = 0.95


@pytest.fixture
def renderings(shapenet_sample):
    """The ShapeNetRendering sample beside the ShapeNetCore.v2 sample."""
    root = shapenet_sample.parent / "ShapeNetRendering"
    if not (root / CHAIRS / CHAIR).is_dir():
        pytest.skip(f"R2N2's renders of {CHAIR} not present under {root}")
    return root


@pytest.fixture
def r2n2_chair(shapenet_sample, renderings):
    """(normalised v2 mesh, metadata rows [24,5], R2N2 alpha masks [24,137,137]) of the shared chair."""
    obj = shapenet_sample / CHAIRS / CHAIR / "models" / "model_normalized.obj"
    mesh, _, _ = normalise_mesh(load_mesh(obj))
    rows = shapenet_rendering.read_metadata(renderings, CHAIRS, CHAIR)
    paths = shapenet_rendering.image_paths(renderings, CHAIRS, CHAIR, len(rows))
    masks = shapenet_rendering.alpha_mask(np.stack([shapenet_rendering.load_rgba(p, 137) for p in paths]))
    return mesh, rows, masks


def view_ious(mesh, rows, masks, layout):
    """Silhouette IoU [V] of R2N2's masks and our renders of `mesh` (in `layout`'s axes)."""
    Ks, world_to_cams = shapenet_rendering.model_cameras(rows, mesh, 137, layout)
    ours = render_views(mesh, Ks, world_to_cams, 137)["mask"]
    return (masks & ours).sum((1, 2)) / (masks | ours).sum((1, 2))


def test_every_real_view_matches_the_v2_mesh(r2n2_chair):
    mesh, rows, masks = r2n2_chair
    assert len(rows) == 24
    ious = view_ious(mesh, rows, masks, "v2")
    assert ious.min() >= MIN_VIEW_IOU, np.round(ious, 3)
    # The v1 convention applied to the v2 mesh is the 90-degree error the v2 frame corrects.
    assert view_ious(mesh, rows[:4], masks[:4], "v1").mean() < 0.8


def test_every_real_view_matches_the_mesh_in_v1_axes(r2n2_chair):
    mesh, rows, masks = r2n2_chair
    v1_mesh = mesh.copy()
    v1_mesh.vertices = mesh.vertices @ FRAME_FROM_V1["v2"]  # p_v1 = M^T p_v2, row vectors
    ious = view_ious(v1_mesh, rows, masks, "v1")
    assert ious.min() >= MIN_VIEW_IOU, np.round(ious, 3)


def test_world_built_from_real_renders_records_their_agreement(
    r2n2_chair, shapenet_sample, renderings, tmp_path, caplog
):
    split = tmp_path / "split.json"
    split.write_text(json.dumps({"train": [CHAIR]}))
    world = ShapeNetWorld(
        "chairs",
        str(shapenet_sample),
        str(tmp_path / "cache"),
        split_file=str(split),
        renderings_root=str(renderings),
        samples_per_shape=2000,
        n_views=6,
        image_size=137,
    )
    assert world.layout == "v2"
    index = world.build()
    with np.load(index.views_path(CHAIR)) as views:
        assert float(views["r2n2_mask_iou"]) >= MIN_VIEW_IOU
        assert views["masks"].shape == (6, 137, 137)
        np.testing.assert_array_equal(views["masks"], r2n2_chair[2][:6])
    assert "overlap our renders" not in caplog.text


def test_a_mesh_in_the_wrong_axes_is_flagged(shapenet_sample, renderings, tmp_path, caplog):
    # The v2 mesh filed as a v1 model: the cameras assume v1 axes, the renders disagree, the build warns.
    v1_root = tmp_path / "ShapeNetCore.v1"
    (v1_root / CHAIRS / CHAIR).mkdir(parents=True)
    (v1_root / CHAIRS / CHAIR / "model.obj").symlink_to(
        shapenet_sample / CHAIRS / CHAIR / "models" / "model_normalized.obj"
    )
    world = ShapeNetWorld(
        "chairs",
        str(v1_root),
        str(tmp_path / "cache"),
        renderings_root=str(renderings),
        samples_per_shape=2000,
        n_views=4,
        image_size=137,
    )
    assert world.layout == "v1"
    with pytest.warns(UserWarning, match="only one shape"):
        index = world.build()
    with np.load(index.views_path(CHAIR)) as views:
        assert float(views["r2n2_mask_iou"]) < shapenet_rendering.AGREEMENT_WARNING
    assert "overlap our renders" in caplog.text
