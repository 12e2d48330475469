"""ShapeNetWorld preprocessing: layout, skipping broken models, idempotence, R2N2 renders and cameras."""

import json

import numpy as np
import pytest
from PIL import Image

from ushape.data.cameras import camera_centre, format_metadata, metadata_to_cameras
from ushape.data.layout import WorldIndex
from ushape.data.real import shapenet_rendering
from ushape.data.real.mesh_sdf import load_mesh, normalise_mesh, sample_mesh_sdf
from ushape.data.real.shapenet_world import SDF_STREAM, ShapeNetWorld
from ushape.data.rendering import render_views
from ushape.data.shape_artifacts import r2n2_frame

CHAIRS = "03001627"
SMALL = dict(samples_per_shape=3000, n_views=2, image_size=32)


def test_world_skips_broken_models_and_is_idempotent(shapenet_tree, tmp_path):
    root = shapenet_tree("v1", ["m0", "m1", "m2", "m3"])
    (root / CHAIRS / "m2" / "model.obj").write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    world = ShapeNetWorld("chairs", str(root), str(tmp_path / "cache"), **SMALL)
    index = world.build()
    assert isinstance(index, WorldIndex) and index.root.parent == tmp_path / "cache" / "shapenet"
    assert index.root.name.startswith(f"{CHAIRS}-")
    skipped = json.loads((index.root / "skipped.json").read_text())
    assert list(skipped) == ["m2"] and "MeshProcessingError" in skipped["m2"]
    assert "m2" not in index.shape_ids() and index.splits["train"]
    for sid in index.shape_ids():
        with np.load(index.sdf_path(sid)) as samples:
            assert samples["pos"].shape[1] == 4 and len(samples["pos"]) + len(samples["neg"]) == 3000
        assert len(index.image_paths(sid)) == 2 and all(p.is_file() for p in index.image_paths(sid))
    stamp = {p: p.stat().st_mtime_ns for p in index.root.rglob("*.npz")}
    again = world.build()
    assert again.splits == index.splits
    assert {p: p.stat().st_mtime_ns for p in index.root.rglob("*.npz")} == stamp


def test_split_file_with_missing_model_and_empty_train(shapenet_tree, tmp_path):
    root = shapenet_tree("v2", ["a", "b"])
    split = tmp_path / "split.json"
    split.write_text(json.dumps({"train": ["a", "ghost"], "test": ["b"]}))
    index = ShapeNetWorld("03001627", str(root), str(tmp_path / "cache"), split_file=str(split), **SMALL).build()
    assert index.splits == {"train": ["a"], "val": [], "test": ["b"]}
    assert "ghost" in json.loads((index.root / "skipped.json").read_text())
    split.write_text(json.dumps({"train": ["ghost"], "test": ["b"]}))
    with pytest.raises(ValueError, match="no usable training shape"):
        ShapeNetWorld("chairs", str(root), str(tmp_path / "cache"), split_file=str(split), **SMALL).build()


def write_r2n2_tree(shapenet_root, render_root, model_id, rows, size=137):
    """A fake ShapeNetRendering entry rendered through ushape's own cameras (a round trip only: the
    real renders in test_real_shapenet_rendering.py check the convention itself)."""
    mesh = load_mesh(shapenet_root / CHAIRS / model_id / "model.obj")
    centre, scale = r2n2_frame(mesh)
    Ks, world_to_cams = metadata_to_cameras(rows, size, r2n2_centre=centre, r2n2_scale=scale)
    views = render_views(mesh, Ks, world_to_cams, size)
    folder = render_root / CHAIRS / model_id / "rendering"
    folder.mkdir(parents=True)
    for v, rgba in enumerate(views["rgba"]):
        Image.fromarray(rgba, mode="RGBA").save(folder / f"{v:02d}.png")
    (folder / "rendering_metadata.txt").write_text(format_metadata(rows))
    return views["mask"]


def test_r2n2_metadata_gives_cameras_that_reproduce_its_renders(shapenet_tree, tmp_path):
    root = shapenet_tree("v1", ["c0", "c1", "c2"])
    rows = np.array([[0.0, 0.0, 0.0, 0.8, 25.0], [135.0, 28.0, 0.0, 0.7, 25.0]])
    for model_id in ("c0", "c1", "c2"):
        write_r2n2_tree(root, tmp_path / "ShapeNetRendering", model_id, rows)
    np.testing.assert_allclose(shapenet_rendering.read_metadata(tmp_path / "ShapeNetRendering", CHAIRS, "c0"), rows)
    with pytest.warns(UserWarning):
        index = ShapeNetWorld(
            "chairs",
            str(root),
            str(tmp_path / "cache"),
            samples_per_shape=2000,
            n_views=2,
            image_size=137,
            renderings_root=str(tmp_path / "ShapeNetRendering"),
        ).build()
    sid = index.shape_ids("train")[0]
    with np.load(index.views_path(sid)) as views:
        # Our normalised frame re-renders R2N2's images pixel for pixel.
        assert float(views["r2n2_mask_iou"]) > 0.99
        mesh, _, _ = normalise_mesh(load_mesh(root / CHAIRS / sid / "model.obj"))
        centre, scale = r2n2_frame(mesh)
        # Azimuth 0, elevation 0: the camera sits on +x at distance_ratio * 1.75 in R2N2 units.
        np.testing.assert_allclose(
            camera_centre(views["world_to_cam"][0]), centre + [0.8 * 1.75 / scale, 0, 0], atol=1e-5
        )
    assert json.loads(index.shape_path(sid).read_text())["views"] == "shapenet_rendering"
    with Image.open(index.image_path(sid, 1)) as image:
        assert image.size == (137, 137) and image.mode == "RGBA"


def test_missing_renders_skip_the_model(shapenet_tree, tmp_path):
    root = shapenet_tree("v1", ["c0", "c1", "c2"])
    rows = np.array([[10.0, 25.0, 0.0, 0.8, 25.0]])
    for model_id in ("c0", "c1"):
        write_r2n2_tree(root, tmp_path / "R", model_id, rows, size=32)
    with pytest.warns(UserWarning):
        index = ShapeNetWorld(
            "chairs",
            str(root),
            str(tmp_path / "cache"),
            samples_per_shape=2000,
            n_views=1,
            image_size=32,
            renderings_root=str(tmp_path / "R"),
        ).build()
    assert "c2" in json.loads((index.root / "skipped.json").read_text())


def test_real_sample_chairs_build(shapenet_sample, tmp_path):
    world = ShapeNetWorld(
        "chairs", str(shapenet_sample), str(tmp_path), samples_per_shape=5000, n_views=1, image_size=48
    )
    with pytest.warns(UserWarning, match="val and test share"):
        index = world.build()
    assert len(index.splits["train"]) == 2 and index.splits["val"] == index.splits["test"]
    for sid in index.shape_ids():
        with np.load(index.sdf_path(sid)) as samples:
            assert len(samples["neg"]) > 250  # real chairs enclose volume
        record = json.loads(index.shape_path(sid).read_text())
        assert record["layout"] == "v2" and record["scale"] > 0
        # How sure the signs are, for filtering: these three chairs are enclosed throughout.
        assert record["sdf_signs"]["samples"] == 5000 and record["sdf_signs"]["confidence"] > 0.99
        # The world's samples are the standalone call's, seeded as the builder seeds each model.
        job = world._job(index, "train", sid)
        rng = np.random.default_rng(np.random.SeedSequence(job.seed, spawn_key=(SDF_STREAM,)))
        mesh, _, _ = normalise_mesh(load_mesh(job.source))
        alone, report = sample_mesh_sdf(mesh, 5000, rng)
        with np.load(index.sdf_path(sid)) as samples:
            for key in ("pos", "neg"):
                np.testing.assert_array_equal(samples[key], alone[key])
        assert report.as_dict() == record["sdf_signs"]
        with Image.open(index.image_path(sid, 0)) as image:
            alpha = np.asarray(image)[..., 3]
        assert 0.02 < (alpha > 0).mean() < 0.8


def test_a_record_rewritten_without_resampling_keeps_its_sign_report(shapenet_sample, tmp_path):
    def make():
        return ShapeNetWorld(
            "chairs",
            str(shapenet_sample),
            str(tmp_path),
            samples_per_shape=3000,
            n_views=1,
            image_size=32,
            max_shapes=1,
        )

    with pytest.warns(UserWarning, match="val and test share"):
        index = make().build()
    sid = index.splits["train"][0]
    before = json.loads(index.shape_path(sid).read_text())["sdf_signs"]
    index.image_path(sid, 0).unlink()  # only the views are remade, so the record is rewritten
    with pytest.warns(UserWarning, match="val and test share"):
        make().build()
    after = json.loads(index.shape_path(sid).read_text())
    assert after["sdf_signs"] == before and before["samples"] == 3000
    assert index.image_path(sid, 0).is_file()
