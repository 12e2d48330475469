import json
from types import SimpleNamespace

import pytest
import torch

from ushape.fusion import BayesianFusion, BayesianKFusion, SharedErrorFusion
from ushape.reconstruction.calibrated_fusion import calibrate_fusion, calibrated_counterpart, default_fusion


def _predictor(tmp_path, fitted: bool):
    if fitted:
        record = {"temperature": 2.0, "sdf_temperature": 1.5}
        record["shared_error"] = {"var": [0.1, 0.2], "view_scale": 0.5, "n_shapes": 4}
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
