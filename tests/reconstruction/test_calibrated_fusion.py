import json
import logging
from types import SimpleNamespace

import pytest
import torch

from ushape.fusion import BayesianFusion, BayesianKFusion, SharedErrorFusion
from ushape.reconstruction.calibrated_fusion import (
    calibrate_fusion,
    calibrated_counterpart,
    default_fusion,
    refinement_prior,
)
from ushape.reconstruction.mesh_std import sdf_distance_scale, sdf_floor, sdf_temperature


def _predictor(tmp_path, fitted: bool, shared_sdf_temperature: float | None = None):
    if fitted:
        record = {"temperature": 2.0, "sdf_temperature": 1.5}
        record["shared_error"] = {"var": [0.1, 0.2], "view_scale": 0.5, "n_shapes": 4}
        if shared_sdf_temperature is not None:
            record["shared_error"]["sdf_temperature"] = shared_sdf_temperature
        (tmp_path / "temperature.json").write_text(json.dumps(record))
    return SimpleNamespace(checkpoint=tmp_path / "best.ckpt", temperature=None, sdf_temperature=None)


def test_default_is_bayesian_until_the_shared_error_is_fitted(tmp_path):
    assert isinstance(default_fusion(_predictor(tmp_path, False)), BayesianFusion)
    predictor = _predictor(tmp_path, True)
    rule = default_fusion(predictor, k=3)
    assert rule.name == "shared-3" and "fitted on val" in rule.calibration
    assert (predictor.temperature, predictor.sdf_temperature) == (2.0, 1.5)  # S was fitted on T-scaled views
    assert torch.allclose(rule(torch.zeros(1, 2), torch.ones(1, 2)).var, torch.tensor([0.6, 0.7]))


def test_shared_without_a_fit_says_how_to_fit_it(tmp_path):
    with pytest.raises(ValueError, match="--fit-temperature"):
        calibrate_fusion(SharedErrorFusion(), _predictor(tmp_path, False))


def test_the_demo_turns_bayesian_k_into_shared_k_only_once_fitted(tmp_path):
    assert isinstance(calibrated_counterpart(BayesianKFusion(2), _predictor(tmp_path, False)), BayesianKFusion)
    assert calibrated_counterpart(BayesianKFusion(2), _predictor(tmp_path, True)).name == "shared-2"
    assert calibrated_counterpart(None, _predictor(tmp_path, True)).name == "shared"


def test_shared_rule_takes_its_own_sdf_temperature_and_old_fits_fall_back_to_the_single_view_one(tmp_path, caplog):
    rule = default_fusion(_predictor(tmp_path, True, shared_sdf_temperature=1.8))
    assert rule.sdf_temperature == 1.8 and "SDF factor 1.8 fitted on val" in rule.calibration  # summary.json says so
    with caplog.at_level(logging.INFO):
        rule = default_fusion(_predictor(tmp_path, True))  # a temperature.json written before the rule had one
    assert rule.sdf_temperature == 1.5 and "single-view T_sdf" in caplog.text


def test_the_meshes_std_takes_the_rules_sdf_temperature_unless_the_code_was_refined(tmp_path):
    predictor = SimpleNamespace(sdf_temperature=1.5)
    shared = default_fusion(_predictor(tmp_path, True, shared_sdf_temperature=1.8))
    assert sdf_temperature(shared, predictor) == 1.8
    refined = {"mode": "masks", "calibration": None}
    assert sdf_temperature(shared, predictor, refined) == 1.5  # a refined posterior is not the fused one
    refined["calibration"] = {"sdf_temperature": 0.6, "sdf_floor": 0.004}  # unless fitted for the refinement
    assert sdf_temperature(shared, predictor, refined) == 0.6 and sdf_floor(shared, refined) == 0.004
    assert sdf_temperature(BayesianFusion(), predictor) == 1.5
    # A factor fitted to grow with the views refined on, T n^beta: read at the record's count (4^0.5 = 2).
    refined["calibration"]["sdf_view_exponent"] = 0.5
    assert sdf_temperature(shared, predictor, refined) == pytest.approx(0.6)  # a record without the count: one view
    refined["views_refined"] = 4
    assert sdf_temperature(shared, predictor, refined) == pytest.approx(1.2)
    refined["calibration"]["seen"] = {"sdf_temperature": 0.3, "sdf_view_exponent": 0.5, "floor_seen": 0.0}
    assert sdf_temperature(shared, predictor, refined) == pytest.approx(0.6)  # the seen model's own factor


def test_the_rules_distance_term_is_read_with_its_fit_and_not_given_to_a_refined_code(tmp_path):
    predictor = _predictor(tmp_path, True, shared_sdf_temperature=0.3)
    record = json.loads((tmp_path / "temperature.json").read_text())
    record["shared_error"].update(sdf_floor=0.012, sdf_distance_scale=0.67)
    (tmp_path / "temperature.json").write_text(json.dumps(record))
    shared = default_fusion(predictor)
    assert (shared.sdf_temperature, shared.sdf_floor, shared.sdf_distance_scale) == (0.3, 0.012, 0.67)
    assert "SDF distance scale 0.67" in shared.calibration  # summary.json's fusion_calibration says so
    assert sdf_distance_scale(shared) == 0.67 and sdf_distance_scale(BayesianFusion()) is None
    assert sdf_distance_scale(shared, {"mode": "masks", "calibration": None}) is None  # refined: its own fit


def test_the_refinement_prior_scales_the_views_itself_and_leaves_the_predictor_alone(tmp_path):
    assert refinement_prior(_predictor(tmp_path, fitted=False)) is None  # no shared error: the caller's Bayes
    plain = _predictor(tmp_path, fitted=True)
    prior = refinement_prior(plain)
    assert plain.temperature is None  # eval.py's predictor is shared by every protocol: not changed
    scaled = default_fusion(_predictor(tmp_path, fitted=True))  # applies T = 2 to the predictor instead
    mu, var = torch.randn(3, 2), torch.rand(3, 2) + 0.1
    ours, theirs = prior(mu, var), scaled(mu, 2.0 * var)  # that predictor would have given 2 var
    torch.testing.assert_close(ours.mu, theirs.mu)
    torch.testing.assert_close(ours.var, theirs.var)
    applied = _predictor(tmp_path, fitted=True)
    applied.temperature = 2.0  # a predictor that already scales its variances: the rule as it is
    torch.testing.assert_close(refinement_prior(applied)(mu, var).var, scaled(mu, var).var)
