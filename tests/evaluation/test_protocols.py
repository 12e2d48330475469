"""Protocol logic: view grouping, deterministic crops, fusion rows, and the whole pipeline on spheres."""

import math
import warnings

import pytest
import torch
from eval_world import LATENT, RADII, FakePredictor, make_run, tiny_protocols, tiny_settings

from ushape.data.augment import (
    CROP_RATIO,
    CompositeBackground,
    corrupted_box,
    corrupted_view,
    crop_box,
    load_rgba,
    resize,
    view_seed,
)
from ushape.evaluation import protocols as P
from ushape.evaluation import tables
from ushape.evaluation.runner import evaluate_all, evaluate_encoder
from ushape.evaluation.views import ViewKey, encode_views


def _keys(n_shapes, n_views):
    return [ViewKey(f"s{s}", v) for s in range(n_shapes) for v in range(n_views)]


def test_views_are_grouped_in_tens_per_shape_and_short_tails_dropped():
    groups = P.group_views(_keys(2, 25), 10)
    assert [(g[0].shape_id, g[0].view, len(g)) for g in groups] == [
        ("s0", 0, 10),
        ("s0", 10, 10),
        ("s1", 0, 10),
        ("s1", 10, 10),
    ]


def test_a_shape_with_few_views_is_one_instance_with_a_warning():
    with pytest.warns(UserWarning, match="fewer than group_size"):
        groups = P.group_views(_keys(1, 3), 10)
    assert len(groups) == 1 and len(groups[0]) == 3


def test_pix3d_mv_drops_shapes_short_of_a_group():
    keys = [ViewKey("a", v) for v in range(11)] + [ViewKey("b", v) for v in range(9)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        groups = P.group_views(keys, 10, drop_short=True)
    assert [(g[0].shape_id, len(g)) for g in groups] == [("a", 10)]


def test_a_view_is_read_with_its_mask_or_as_the_photo(tmp_path):
    from PIL import Image

    from ushape.evaluation.views import load_view

    pixels = torch.tensor([[[200, 100, 0, 255], [40, 80, 120, 0]]], dtype=torch.uint8).numpy()
    Image.fromarray(pixels, mode="RGBA").save(tmp_path / "v.png")
    masked, photo = load_view(tmp_path / "v.png", "gt_mask"), load_view(tmp_path / "v.png", "none")
    assert torch.allclose(masked[:, 0, 1], torch.zeros(4))  # outside the mask: nothing (premultiplied)
    assert torch.allclose(photo[:, 0, 1], torch.tensor([40, 80, 120, 255]) / 255.0)  # the background, opaque
    assert torch.allclose(masked[:, 0, 0], photo[:, 0, 0])
    with pytest.raises(ValueError, match="mask_input"):
        load_view(tmp_path / "v.png", "seg")


def test_view_seeds_depend_on_the_view_only():
    assert view_seed(0, "a", 1) == view_seed(0, "a", 1)
    assert len({view_seed(0, "a", 1), view_seed(0, "a", 2), view_seed(0, "b", 1), view_seed(1, "a", 1)}) == 4


def test_crops_are_deterministic_and_full_scale_keeps_the_image(sphere_world):
    rgba = load_rgba(sphere_world.image_path("test_0", 0))
    a = corrupted_view(rgba, 32, 0.1, seed=7)
    assert torch.equal(a, corrupted_view(rgba, 32, 0.1, seed=7))
    assert not torch.equal(a, corrupted_view(rgba, 32, 0.1, seed=8))
    whole = CompositeBackground("gt_mask", 1.0)(resize(rgba, 32))
    assert torch.equal(corrupted_view(rgba, 32, 1.0, seed=7), whole)


@pytest.mark.parametrize("mask_mode", ["gt_mask", "none"])
def test_corrupted_box_is_the_crop_corrupted_view_takes(sphere_world, mask_mode):
    rgba = load_rgba(sphere_world.image_path("test_1", 3))
    for min_scale, seed in ((0.1, 7), (0.01, 3), (1.0, 5)):
        top, left, h, w = corrupted_box(rgba.shape[-2], rgba.shape[-1], min_scale, seed)
        generator = torch.Generator().manual_seed(seed)
        crop_box(rgba.shape[-2], rgba.shape[-1], min_scale, CROP_RATIO, generator)  # the box's draws come first
        expected = CompositeBackground(mask_mode, 1.0)(resize(rgba[:, top : top + h, left : left + w], 32), generator)
        assert torch.equal(corrupted_view(rgba, 32, min_scale, seed, mask_mode), expected)


def test_fusion_methods_of_a_deterministic_encoder_are_averaging_only():
    assert list(P.fusion_methods(False, [1, 2])) == ["average"]
    assert list(P.fusion_methods(True, [1, 2])) == ["average", "bayesian", "bayesian-1", "bayesian-2"]


def test_summarise_averages_cd_over_non_empty_reconstructions():
    base = {
        "encoder": "es",
        "label": "Ours",
        "protocol": "single",
        "min_scale": 1.0,
        "method": "single-view",
        "views": 1,
        "shape_id": "a",
    }
    rows = P.summarise(
        [{**base, "item": "0", "iou": 0.5, "cd": 0.2}, {**base, "item": "1", "iou": 0.0, "cd": math.nan}]
    )
    assert rows[0]["iou"] == 0.25 and rows[0]["cd"] == 0.2 and rows[0]["empty"] == 1 and rows[0]["n"] == 2


def test_encodings_are_cached_and_reused(sphere_world, tmp_path):
    predictor = FakePredictor(tmp_path / "x.ckpt")
    predictor.checkpoint.write_bytes(b"x")
    keys = [ViewKey("test_0", v) for v in range(3)]
    first = encode_views(predictor, sphere_world, keys, 0.5, cache_dir=tmp_path)
    predictor.encode = None  # a second call must not encode again
    second = encode_views(predictor, sphere_world, keys, 0.5, cache_dir=tmp_path)
    assert torch.equal(first.mu, second.mu) and len(list(tmp_path.glob("enc_*.pt"))) == 1


def test_another_world_with_the_same_shape_ids_is_encoded_anew(sphere_world, tmp_path):
    from eval_world import build_sphere_world

    other = build_sphere_world(tmp_path / "other")  # same ids, views drawn again
    predictor = FakePredictor(tmp_path / "x.ckpt")
    predictor.checkpoint.write_bytes(b"x")
    keys = [ViewKey("test_0", v) for v in range(3)]
    encode_views(predictor, sphere_world, keys, 1.0, cache_dir=tmp_path / "cache")
    encode_views(predictor, other, keys, 1.0, cache_dir=tmp_path / "cache")
    assert len(list((tmp_path / "cache").glob("enc_*.pt"))) == 2


def test_sphere_pipeline_scores_good_reconstructions_and_corruption_hurts(sphere_world, sphere_codes, tmp_path):
    settings, protocols = tiny_settings(), tiny_protocols(["single_view", "multi_view", "corrupted"])
    run = make_run(sphere_world, sphere_codes, tmp_path / "cache", "es", tmp_path, settings)
    out = evaluate_encoder(run, settings, tmp_path / "cache", protocols=protocols)
    cells = {(r["protocol"], r["min_scale"], r["method"]): r for r in P.summarise(out["records"])}
    clean = cells[("single", 1.0, "single-view")]
    assert clean["n"] == len(RADII) * 8 and clean["iou"] > 0.8 and "emd" in clean
    assert cells[("single", 0.1, "single-view")]["iou"] < clean["iou"]
    # 2 shapes x 8 views in instances of 4: 4 instances per fusion method.
    assert cells[("multi", 1.0, "bayesian-3")]["n"] == 4 and cells[("multi", 1.0, "bayesian")]["views"] == 4
    assert ("multi", 0.4, "bayesian-2") in cells and ("multi", 0.4, "bayesian-3") not in cells


def test_setting_row_warns_when_k_exceeds_the_views(sphere_world, sphere_codes, tmp_path):
    from ushape.fusion.strategies import BayesianKFusion

    settings = tiny_settings()
    run = make_run(sphere_world, sphere_codes, None, "es", tmp_path, settings)
    with pytest.warns(UserWarning, match="only 4 views"):
        out = evaluate_encoder(run, settings, None, setting=(BayesianKFusion(k=6), "bayesian-6", 1.0))
    (row,) = out["rows"]
    assert row["fusion"] == "bayesian-6" and row["n_instances"] == 4 and 0 < row["multi_view_iou"] <= 1
    assert out["records"] == []


def test_evaluate_all_runs_the_uncertainty_analysis_with_the_equal_variance_baseline(
    sphere_world, sphere_codes, tmp_path
):
    settings = tiny_settings()
    runs = [make_run(sphere_world, sphere_codes, None, name, tmp_path, settings) for name in ("es", "l2")]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = evaluate_all(runs, settings, protocols=tiny_protocols(["uncertainty"]))
    kinds = {(r["encoder"], r["space"], r["variance"], r["method"]) for r in result["uncertainty"]}
    assert ("es", "sdf", "predicted", "linearised") in kinds and ("es", "latent", "equal", "-") in kinds
    assert ("l2", "sdf", "predicted", "mc") not in kinds and ("l2", "sdf", "equal", "mc") in kinds
    sdf = {(r["encoder"], r["variance"], r["method"]): r for r in result["uncertainty"] if r["space"] == "sdf"}
    # Unit latent variance through a decoder whose radius moves 0.1 tanh(z): far too wide for these errors.
    assert sdf[("es", "predicted", "mc")]["nll_all"] < sdf[("es", "equal", "mc")]["nll_all"]
    assert set(result["curves"]["latent"]) == {"Ours (predicted var)", "Ours (equal var)", "FroDO* (equal var)"}


def test_view_calibration_protocol_scores_every_rule_and_writes_table_v(sphere_world, sphere_codes, tmp_path):
    import json

    from ushape.evaluation.report import build_figures, build_tables

    settings = tiny_settings()
    run = make_run(sphere_world, sphere_codes, None, "es", tmp_path, settings)
    record = {"temperature": 1.0, "shared_error": {"var": [0.1] * LATENT, "view_scale": 1.0}}
    record["shared_error"]["n_shapes"] = 2
    (run.predictor.checkpoint.parent / "temperature.json").write_text(json.dumps(record))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = evaluate_all([run], settings, protocols=tiny_protocols(["view_calibration"]))
    rows = result["view_calibration"]
    assert {r["fusion"] for r in rows} >= {"bayesian", "shared", "intersection"}
    assert all(0 <= r["latent_calibration_error"] <= 0.5 and 0 <= r["sdf_coverage90"] <= 1 for r in rows)
    assert any(t.name.startswith("Table V") for t in build_tables(result))
    assert "calibration_across_views" in build_figures(result)


def test_table3_fuses_by_the_calibrated_shared_rule_once_it_is_fitted(sphere_world, sphere_codes, tmp_path):
    import json

    from ushape.evaluation.view_calibration import calibrated_rule

    settings = tiny_settings()
    run = make_run(sphere_world, sphere_codes, None, "es", tmp_path, settings)
    assert calibrated_rule(run) == {}  # nothing fitted: the paper's rules only
    records = evaluate_encoder(run, settings, None, protocols=tiny_protocols(["multi_view"]))["records"]
    assert "shared" not in {r["method"] for r in records}
    shared = {"var": [0.1] * LATENT, "view_scale": 0.5, "n_shapes": 3}
    (tmp_path / "temperature.json").write_text(json.dumps({"temperature": 2.0, "shared_error": shared}))
    # Fitted on variances scaled by T = 2: S + c (sum_v (T var_v)^-1)^-1 = 0.1 + 0.5 * 2 * 1 / 2.
    fused = calibrated_rule(run)["shared"](torch.zeros(2, LATENT), torch.ones(2, LATENT))
    assert torch.allclose(fused.var, torch.full((LATENT,), 0.6))
    run.predictor.temperature = 2.0  # applied by the predictor already: not again
    assert torch.allclose(
        calibrated_rule(run)["shared"](torch.zeros(2, LATENT), torch.ones(2, LATENT)).var, torch.full((LATENT,), 0.35)
    )
    summary = P.summarise(evaluate_encoder(run, settings, None, protocols=tiny_protocols(["multi_view"]))["records"])
    cells = {r["method"]: r for r in summary}
    assert cells["shared"]["n"] == cells["bayesian"]["n"] == 4
    # Bayesian's mean (fuse_shared returns fuse_bayesian's own): only a refinement tells them apart
    assert cells["shared"]["iou"] == cells["bayesian"]["iou"]
    assert [row[2] for row in tables.table3(summary, 4).rows][-1] == "Shared (calibrated Bayesian)"
