"""The refinement as an evaluation method: its rows in every table, on the evaluation's own crops, once per
fused instance, cached, with its fallbacks counted; and the method hook's post-fusion step in general.

The ellipsoid world's renders are discs, not the ellipsoid seen by its cameras, so on it what the
refinement reaches says nothing; what it is fed, and where its results go, does. Two known answers:
the ellipsoid decoder ignores code dimensions 1 and 2, so no view moves them and the refined posterior
keeps their prior variance exactly; and with the true silhouettes in views.npz, a view refined on its
evaluation crop recovers the thin ellipsoid's axis.
"""

import logging
import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from eval_world import IMAGE, RADII, build_sphere_world, make_run, tiny_protocols, tiny_settings

import ushape.evaluation.refine_method as R
import ushape.evaluation.views as V
from ushape.data.augment import CROP_RATIO, crop_box, view_seed
from ushape.data.rendering import render_mesh
from ushape.evaluation.context import EvalContext
from ushape.evaluation.methods import ReconstructionMethod, fallback_lines
from ushape.evaluation.report import build_tables
from ushape.evaluation.runner import evaluate_all
from ushape.evaluation.views import Estimate, encode_views
from ushape.fusion.rules import fuse_bayesian

PROTOCOLS = ("single_view", "multi_view", "corrupted", "uncertainty", "locality")
FAST = dict(size=4, iterations=2)  # 4 x 4 rays, 2 steps: seconds for the whole world


def _evaluate(world, codes, tmp_path, cache, methods, protocols=PROTOCOLS, **protocol_settings):
    settings = tiny_settings()
    checkpoint = tmp_path / "es.ckpt"
    stamp = checkpoint.stat().st_mtime_ns if checkpoint.is_file() else None
    run = make_run(world, codes, cache, "es", tmp_path, settings)
    if stamp is not None:  # make_run rewrites the checkpoint: the same encoder keeps its time (its cache key)
        os.utime(checkpoint, ns=(stamp, stamp))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return evaluate_all(
            [run], settings, cache, protocols=tiny_protocols(protocols, **protocol_settings), methods=methods
        )


@pytest.fixture(scope="module")
def refined(sphere_world, sphere_codes, tmp_path_factory):
    """Every reconstructing protocol for a fake ES encoder, plainly and refined on masks, with a cache."""
    tmp = tmp_path_factory.mktemp("refined")
    method = R.RefineMethod("masks", **FAST)
    result = _evaluate(sphere_world, sphere_codes, tmp, tmp / "cache", [method], corrupted=dict(scales=(0.1,)))
    return result, tmp


def test_refined_rows_stand_beside_the_plain_ones_in_every_table(refined):
    result, _ = refined
    cells = {(r["encoder"], r["protocol"], r["min_scale"], r["method"]): r for r in result["summary"]}
    for key in [k for k in cells if k[0] == "es"]:
        plain, mine = cells[key], cells[("es+refine_masks", *key[1:])]
        assert mine["n"] == plain["n"] and mine["label"] == "Ours + refine (masks)"
        assert mine["fallbacks"] == 0 and "fallbacks" not in plain
    tables = {t.name.split(":")[0]: t for t in build_tables(result)}
    for name in ("Table 1", "Table 3", "Table 4", "Table S1", "Table U", "Table L"):
        assert any(str(row[0]).startswith("Ours + refine (masks)") for row in tables[name].rows), name
    refined_locality = [r for r in result["locality"] if r["encoder"] == "es+refine_masks"]
    assert refined_locality and refined_locality[0]["n_views"] == 16


@pytest.fixture(scope="module")
def silhouette_world(tmp_path_factory):
    """The ellipsoid world with each view's true mask and depth in views.npz (rendered from its camera)."""
    world = build_sphere_world(tmp_path_factory.mktemp("silhouettes"))
    for shape_id in RADII:
        mesh = trimesh.load(world.mesh_path(shape_id), force="mesh", process=False)
        with np.load(world.views_path(shape_id)) as cameras:
            K, w2c = cameras["K"], cameras["world_to_cam"]
        renders = [render_mesh(mesh, K[v], w2c[v], IMAGE) for v in range(len(K))]
        masks, depth = np.stack([r["mask"] for r in renders]), np.stack([r["depth"] for r in renders])
        np.savez(world.views_path(shape_id), K=K, world_to_cam=w2c, masks=masks, depth=depth)
    return world


@pytest.mark.parametrize("mode", ["masks", "depth"])
def test_cropped_views_pull_the_code_to_the_shape_they_show(silhouette_world, sphere_codes, tmp_path, mode):
    """With true silhouettes, refining each 0.1-cropped view of the thin ellipsoid (a = 0.3) on its crop brings
    a back towards 0.3 from the fake encoder's cropped guess: the crop's camera and pixels agree. (The crop's
    mask with the whole image's K drives a to 0.21 or 0.54 instead.) Views whose guess saturates the decoder's
    tanh (a = 0.797) carry no gradient and are left out."""
    settings = tiny_settings()
    run = make_run(silhouette_world, sphere_codes, None, "es", tmp_path, settings)
    run.method = R.RefineMethod(mode, size=16, iterations=10)
    context = EvalContext(run, settings, None, {})
    prior, refined = context.encode(0.1), context.views(0.1)
    a_prior, a_refined = (0.5 + 0.3 * torch.tanh(e.mu[:, 0]) for e in (prior, refined))
    thin = torch.tensor([k.shape_id == "test_0" for k in prior.keys]) & (a_prior < 0.79)
    error_prior, error_refined = (a_prior - 0.3).abs()[thin], (a_refined - 0.3).abs()[thin]
    assert int(thin.sum()) >= 6 and refined.fallbacks == (None,) * 16
    assert (error_refined < error_prior).all() and error_refined.mean() < 0.5 * error_prior.mean()


def test_table_d_propagates_the_refined_covariance_to_depth(sphere_world, sphere_codes, tmp_path):
    method = R.RefineMethod("masks", **FAST)
    result = _evaluate(sphere_world, sphere_codes, tmp_path, None, [method], ("depth",), depth=dict(views=1))
    rows = {(r["encoder"], r["method"]): r for r in result["depth"]}
    for kind in ("implicit", "mc M=10"):
        plain, refined = rows[("es", kind)], rows[("es+refine_masks", kind)]
        assert refined["n_views"] == plain["n_views"] == 2 and refined["mean_std"] != plain["mean_std"]
    (table,) = [t for t in build_tables(result) if t.name.startswith("Table D")]
    assert "Ours + refine (masks)" in {row[0] for row in table.rows}


def test_refined_views_keep_the_prior_where_no_view_looks(sphere_world, sphere_codes, tmp_path):
    settings = tiny_settings()
    run = make_run(sphere_world, sphere_codes, None, "es", tmp_path, settings)
    run.method = R.RefineMethod("masks", size=8, iterations=3)
    context = EvalContext(run, settings, None, {})
    prior, views = context.encode(0.1), context.views(0.1, 1)
    assert views.var.shape == (2, 3, 3) and views.fallbacks == (None, None)  # full covariances, none fell back
    kept = prior.first_views(1).var[:, 1:]
    assert torch.allclose(torch.diagonal(views.var, dim1=1, dim2=2)[:, 1:], kept, rtol=1e-5)
    # exact: the decoder reads z_0 alone, so its Jacobian is 0 elsewhere and the precision and its inverse stay diagonal
    assert torch.equal(views.var[:, 0, 1:], torch.zeros(2, 2))
    assert not torch.equal(views.mu[:, 0], prior.first_views(1).mu[:, 0])  # the one dimension a view moves


def test_a_view_is_refined_on_the_crop_its_plain_row_was_encoded_from(
    sphere_world, sphere_codes, tmp_path, monkeypatch
):
    encoded, refined_on = {}, {}
    corrupted_view, corrupted_box = V.corrupted_view, R.corrupted_box

    def encoder_input(rgba, size, min_scale, seed, *args):
        height, width = rgba.shape[-2:]  # corrupted_view's box: its generator's first draws (test_protocols)
        encoded[(min_scale, seed)] = crop_box(height, width, min_scale, CROP_RATIO, torch.Generator().manual_seed(seed))
        return corrupted_view(rgba, size, min_scale, seed, *args)

    def refinement_box(height, width, min_scale, seed):
        refined_on[(min_scale, seed)] = corrupted_box(height, width, min_scale, seed)
        return refined_on[(min_scale, seed)]

    monkeypatch.setattr(V, "corrupted_view", encoder_input)
    monkeypatch.setattr(R, "corrupted_box", refinement_box)
    method = R.RefineMethod("masks", **FAST)
    _evaluate(sphere_world, sphere_codes, tmp_path, None, [method], ("locality",))  # clean and 0.1 crops
    assert {scale for scale, _ in refined_on} == {1.0, 0.1} and len(refined_on) == 32
    assert set(refined_on) <= set(encoded)
    for key, box in refined_on.items():
        assert encoded[key] == box, key


def test_the_crop_box_of_a_corrupted_view_is_the_evaluations(sphere_world):
    from ushape.evaluation.views import ViewKey

    key = ViewKey("test_1", 5)
    view = R.evaluation_view(R.EvaluationView(sphere_world, key, 0.1, 0))
    top, left, h, w = crop_box(32, 32, 0.1, CROP_RATIO, torch.Generator().manual_seed(view_seed(0, "test_1", 5)))
    assert view.image_hw == (h, w) and (h, w) != (32, 32)
    assert view.K[0, 2] == pytest.approx(16.0 - left) and view.K[1, 2] == pytest.approx(16.0 - top)
    (whole,) = [R.stored_view(sphere_world, key)]
    assert torch.equal(view.mask, whole.mask[top : top + h, left : left + w]) and bool(view.observed.all())


class Tagged(ReconstructionMethod):
    """Every Gaussian after fusion replaced by the first shape's code, the calls recorded."""

    name, label = "tagged", "tagged"

    def __init__(self, code):
        self.code, self.calls = code, []

    def after_fusion(self, context, fused, keys, min_scale):
        self.calls.append((tuple(keys), min_scale, fused))
        return Estimate(self.code, fused.var, fallback="tagged" if keys[0].shape_id == "test_1" else None)


def test_the_step_after_fusion_runs_once_per_view_and_fused_instance(sphere_world, sphere_codes, tmp_path):
    method = Tagged(torch.zeros(3))
    result = _evaluate(sphere_world, sphere_codes, tmp_path, None, [method], ("single_view", "multi_view"))
    single = [c for c in method.calls if len(c[0]) == 1]
    fused = [c for c in method.calls if len(c[0]) > 1]
    assert len(single) == len({c[0] for c in single}) == 16  # each view once, at the clean crop
    rules = ("average", "bayesian", "bayesian-1", "bayesian-2", "bayesian-3")
    instances = {c[0] for c in fused}
    assert len(instances) == 4 and all(sum(c[0] == keys for c in fused) == len(rules) for keys in instances)
    predictor = make_run(sphere_world, sphere_codes, None, "es", tmp_path, tiny_settings()).predictor
    first = list(fused[0][0])
    bayesian = fuse_bayesian(*encode_views(predictor, sphere_world, first, 1.0).select(first))
    # The evaluation encodes a shape's views in one batch, this check only the instance's: batched
    # matrix products may differ in the last bits between batchings (they do on AVX2-only CPUs), so
    # the same fused Gaussian is matched to float32 rounding, not bit for bit.
    assert any(
        torch.allclose(c[2].mu, bayesian.mu, rtol=1e-5, atol=1e-6)
        and torch.allclose(c[2].var, bayesian.var, rtol=1e-5, atol=1e-9)
        for c in fused
        if c[0] == tuple(first)
    )
    records = [r for r in result["records"] if r["encoder"] == "es+tagged"]
    assert {r["iou"] for r in records if r["shape_id"] == "test_0"} == {
        r["iou"] for r in records if r["shape_id"] == "test_0" and r["protocol"] == "single"
    }
    cells = {(r["encoder"], r["protocol"], r["method"]): r for r in result["summary"]}
    assert cells[("es+tagged", "single", "single-view")]["fallbacks"] == 8  # test_1's views
    assert cells[("es+tagged", "multi", "bayesian")]["fallbacks"] == 2  # test_1's two instances
    assert "Ours + tagged, multi view(s) at min_scale 1: 10 of 20 reconstructions fell back to their input" in (
        fallback_lines(result["summary"])
    )


def test_refinements_are_cached_and_reused(refined, sphere_world, sphere_codes, monkeypatch):
    result, tmp = refined
    files = sorted((tmp / "cache" / R.CACHE_FOLDER).glob("*.pt"))
    assert files and not list((tmp / "cache" / R.CACHE_FOLDER).glob("*.tmp*"))

    def no_refinement(*args, **kwargs):
        raise AssertionError("refined again although cached")

    monkeypatch.setattr(R, "refine", no_refinement)
    method = R.RefineMethod("masks", **FAST)
    again = _evaluate(sphere_world, sphere_codes, tmp, tmp / "cache", [method], corrupted=dict(scales=(0.1,)))
    mine = [r for r in result["records"] if r["encoder"] == "es+refine_masks"]
    assert [r for r in again["records"] if r["encoder"] == "es+refine_masks"] == mine
    assert sorted((tmp / "cache" / R.CACHE_FOLDER).glob("*.pt")) == files
    other = R.RefineMethod("depth", **FAST)  # other settings: another key, so it would refine
    with pytest.raises(AssertionError, match="refined again"):
        _evaluate(sphere_world, sphere_codes, tmp, tmp / "cache", [other], ("single_view",))


def test_views_without_cameras_fall_back_and_are_counted(sphere_codes, tmp_path, caplog):
    world = build_sphere_world(tmp_path / "world")
    world.views_path("test_1").unlink()
    with caplog.at_level(logging.INFO):
        result = _evaluate(
            world, sphere_codes, tmp_path, None, [R.RefineMethod("depth", **FAST)], ("single_view", "multi_view")
        )
    cells = {(r["encoder"], r["protocol"], r["method"]): r for r in result["summary"]}
    assert cells[("es+refine_depth", "single", "single-view")]["fallbacks"] == 8
    assert cells[("es+refine_depth", "multi", "average")]["fallbacks"] == 2
    fell = [r for r in result["records"] if r.get("fallback")]
    assert {r["shape_id"] for r in fell} == {"test_1"} and fell[0]["fallback"] == "no view has a camera"
    assert "Ours + refine (depth), single view(s) at min_scale 1: 8 of 16 reconstructions fell back" in caplog.text
    shutil.rmtree(world.root)


class Halved(ReconstructionMethod):
    """Every fused Gaussian's covariance halved and made full: its latent error / variance doubles."""

    name, label = "halved", "halved"

    def after_fusion(self, context, fused, keys, min_scale):
        var = fused.var if fused.var.ndim == 2 else torch.diag(fused.var)
        return Estimate(fused.mu, 0.5 * var)


def test_table_v_scores_a_method_on_every_fused_subset(sphere_world, sphere_codes, tmp_path):
    import json

    record = {"temperature": 1.0, "shared_error": {"var": [0.1] * 3, "view_scale": 1.0, "n_shapes": 2}}
    (tmp_path / "temperature.json").write_text(json.dumps(record))
    result = _evaluate(sphere_world, sphere_codes, tmp_path, None, [Halved(), Same()], ("view_calibration",))
    rows = {(r["encoder"], r["fusion"], r["n_views"]): r for r in result["view_calibration"]}
    assert not any(encoder == "es+same" for encoder, _, _ in rows)  # no step after fusion: the plain rows say it
    for (encoder, rule, n), plain in [(k, r) for k, r in rows.items() if k[0] == "es"]:
        halved = rows[("es+halved", rule, n)]
        assert halved["latent_error_over_var"] == pytest.approx(2 * plain["latent_error_over_var"], rel=1e-5)
        assert halved["sdf_error_over_var"] == pytest.approx(2 * plain["sdf_error_over_var"], rel=1e-3)


class Same(ReconstructionMethod):
    name, label = "same", "same codes"


class HalvedRecalibrated(Halved):
    """Halved, with the SDF variance calibration fitted for it: T_sdf = 2 gives the SDF variance back."""

    name, label = "halved_t", "halved, recalibrated"
    sdf_calibration = (2.0, None)


def test_a_methods_own_sdf_calibration_scales_its_sdf_variance_in_tables_v_and_s1(sphere_world, sphere_codes, tmp_path):
    import json

    record = {"temperature": 1.0, "shared_error": {"var": [0.1] * 3, "view_scale": 1.0, "n_shapes": 2}}
    (tmp_path / "temperature.json").write_text(json.dumps(record))
    protocols = ("view_calibration", "uncertainty")
    result = _evaluate(sphere_world, sphere_codes, tmp_path, None, [HalvedRecalibrated()], protocols)
    rows = {(r["encoder"], r["fusion"], r["n_views"]): r for r in result["view_calibration"]}
    for (encoder, rule, n), plain in [(k, r) for k, r in rows.items() if k[0] == "es"]:
        mine = rows[("es+halved_t", rule, n)]
        assert mine["latent_error_over_var"] == pytest.approx(2 * plain["latent_error_over_var"], rel=1e-5)
        assert mine["sdf_error_over_var"] == pytest.approx(plain["sdf_error_over_var"], rel=1e-3)
    sdf = {
        (r["encoder"], r["method"]): r["calibration_error"]
        for r in result["uncertainty"]
        if r["space"] == "sdf" and r["variance"] == "predicted"
    }
    for method in ("linearised",):
        assert sdf[("es+halved_t", method)] == pytest.approx(sdf[("es", method)], abs=1e-6)


def test_starts_reach_the_settings_from_the_method_config_and_bad_counts_are_refused():
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    config = OmegaConf.load(Path(__file__).parents[2] / "conf" / "method" / "refine_depth.yaml")
    assert instantiate(config).settings.starts == 0  # from the fused mean, as measured by default
    assert instantiate(config, starts=8).settings.starts == 8
    with pytest.raises(ValueError, match="starts"):
        R.RefineMethod("depth", starts=-1)


def test_pose_estimated_rows_stand_beside_the_known_camera_rows(sphere_world, sphere_codes, tmp_path):
    """`methods=[refine_masks, refine_masks_pose]`: the same views and crops, the second with the pose hidden; its
    results are cached like the first's."""
    from ushape.evaluation.pose_refine_method import PoseRefineMethod

    methods = [R.RefineMethod("masks", **FAST), PoseRefineMethod("masks", pose={"azimuths": 2}, **FAST)]
    result = _evaluate(sphere_world, sphere_codes, tmp_path, tmp_path / "cache", methods, ("single_view",))
    cells = {r["encoder"]: r for r in result["summary"] if r["protocol"] == "single"}
    known, posed = cells["es+refine_masks"], cells["es+refine_masks_pose"]
    assert posed["n"] == known["n"] and posed["label"] == "Ours + refine (masks, pose estimated)"
    assert posed["fallbacks"] == 0
    assert list((tmp_path / "cache" / R.CACHE_FOLDER).glob("pose_*.pt"))
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    rgbd = instantiate(OmegaConf.load(Path(__file__).parents[2] / "conf" / "method" / "refine_depth_pose.yaml"))
    assert (rgbd.name, rgbd.settings.mode) == ("refine_depth_pose", "depth")
    assert rgbd.label == "refine (depth, pose estimated)"
