"""Known answers of the latent- and SDF-space uncertainty scores."""

import math

import pytest
import torch

from ushape.evaluation.uncertainty import (
    latent_nll,
    latent_report,
    region_masks,
    sdf_region_scores,
)
from ushape.metrics.scores import energy_score_1d
from ushape.propagation import propagate_to_sdf


class LinearDecoder(torch.nn.Module):
    """f(x, z) = x_0 + w . z: linear in the code, so first-order propagation is exact."""

    def __init__(self, w):
        super().__init__()
        self.w = torch.nn.Parameter(torch.as_tensor(w, dtype=torch.float32))

    def forward(self, xyz, z):
        return xyz[..., 0] + (z * self.w).sum(-1)


def test_latent_nll_is_the_full_gaussian_log_density():
    torch.manual_seed(0)
    mu, target = torch.randn(5, 4), torch.randn(5, 4)
    var = torch.rand(5, 4) + 0.1
    expected = -torch.distributions.Normal(mu, var.sqrt()).log_prob(target).sum(-1).mean()
    assert latent_nll(mu, var, target) == pytest.approx(float(expected), rel=1e-5)


def test_latent_report_prefers_a_calibrated_variance():
    torch.manual_seed(0)
    mu = torch.zeros(2000, 8)
    target = 0.1 * torch.randn(2000, 8)
    good = latent_report(mu, torch.full_like(mu, 0.01), target)
    equal = latent_report(mu, torch.ones_like(mu), target)
    assert good["calibration_error"] < 0.03 < equal["calibration_error"]
    assert good["nll"] < equal["nll"] and good["es"] < equal["es"]
    assert good["l2"] == pytest.approx(equal["l2"])


def test_regions_split_at_the_surface_band():
    sdf = torch.tensor([-0.2, -0.005, 0.0, 0.009, 0.01, 0.5])
    masks = region_masks(sdf, 0.01)
    assert masks["surface"].tolist() == [False, True, True, True, False, False]
    assert (masks["surface"] ^ masks["non_surface"]).all() and masks["all"].all()


def test_sdf_region_scores_average_per_region():
    mean = torch.zeros(4)
    var = torch.full((4,), 0.25)
    sdf = torch.tensor([0.0, 0.005, 0.5, -0.5])
    scores = sdf_region_scores(mean, var, sdf)
    es = energy_score_1d(mean, var, sdf)
    assert scores["es_surface"] == pytest.approx(float(es[:2].mean()))
    assert scores["es_non_surface"] == pytest.approx(float(es[2:].mean()))
    assert scores["n_surface"] == 2 and scores["n_all"] == 4
    assert scores["nll_all"] == pytest.approx(0.5 * math.log(2 * math.pi * 0.25) + float((sdf**2).mean() / 0.5))


def test_empty_region_scores_nan():
    scores = sdf_region_scores(torch.zeros(2), torch.ones(2), torch.tensor([0.5, 0.6]))
    assert math.isnan(scores["es_surface"]) and scores["n_surface"] == 0


def test_linearised_propagation_is_exact_for_a_linear_decoder_and_mc_agrees():
    w = [0.02, -0.01, 0.03]
    decoder = LinearDecoder(w)
    mu, var = torch.zeros(3), torch.tensor([1.0, 4.0, 0.25])
    points = torch.tensor([[0.0, 0, 0], [0.05, 0, 0]])
    mean, variance = propagate_to_sdf(decoder, mu, var, points, "linearised", clamp=None)
    expected = sum(wi**2 * vi for wi, vi in zip(w, var.tolist()))
    torch.testing.assert_close(variance, torch.full((2,), expected))
    torch.testing.assert_close(mean, points[:, 0])
    _, mc_var = propagate_to_sdf(decoder, mu, var, points, "mc", n_samples=4000, clamp=None)
    torch.testing.assert_close(mc_var, torch.full((2,), expected), rtol=0.1, atol=0.0)


def test_clamped_propagation_has_no_spread_beyond_the_clamp():
    decoder = LinearDecoder([0.001])
    points = torch.tensor([[0.5, 0, 0], [0.0, 0, 0]])
    mean, variance = propagate_to_sdf(decoder, torch.zeros(1), torch.ones(1), points, "linearised", clamp=0.1)
    assert mean.tolist() == pytest.approx([0.1, 0.0]) and variance[0] == 0 and variance[1] > 0
    mean, variance = propagate_to_sdf(decoder, torch.zeros(1), torch.ones(1), points, "mc", clamp=0.1)
    assert mean[0] == pytest.approx(0.1) and variance[0] == 0


def _encodings(errors, traces):
    """Views of one shape whose code is 0: mean error `errors[i]` along dim 0, variance trace `traces[i]`."""
    from ushape.evaluation.views import Encodings, ViewKey

    n, d = len(errors), 4
    mu = torch.zeros(n, d)
    mu[:, 0] = torch.tensor(errors, dtype=torch.float32)
    var = torch.tensor(traces, dtype=torch.float32)[:, None].expand(n, d) / d
    return Encodings([ViewKey("s", i) for i in range(n)], mu, var.contiguous())


def test_error_tracking_ranks_variance_against_error():
    from ushape.decoder.artifacts import CodeTable
    from ushape.evaluation.protocols import EncoderSpec
    from ushape.evaluation.uncertainty_protocol import error_tracking_row

    codes = CodeTable(["s"], torch.zeros(1, 4))
    ours = EncoderSpec("es", "Ours", True)
    tracking = error_tracking_row(ours, _encodings([0.1, 0.5, 0.2, 0.9], [1.0, 3.0, 2.0, 4.0]), codes, 0.1)
    assert tracking["rank_corr"] == pytest.approx(1.0)
    assert tracking["l2"] == pytest.approx((0.1 + 0.5 + 0.2 + 0.9) / 4)
    assert tracking["var_trace"] == pytest.approx(2.5) and tracking["min_scale"] == 0.1 and tracking["n"] == 4
    reversed_ = error_tracking_row(ours, _encodings([0.1, 0.5, 0.2, 0.9], [4.0, 2.0, 3.0, 1.0]), codes, 1.0)
    assert reversed_["rank_corr"] == pytest.approx(-1.0)
    frodo = error_tracking_row(EncoderSpec("l2", "FroDO*", False), _encodings([0.1, 0.5], [4.0, 4.0]), codes, 1.0)
    assert math.isnan(frodo["rank_corr"])


def test_sdf_rows_scale_the_predicted_sdf_variance_by_the_sdf_temperature_only(tmp_path):
    import numpy as np
    from analytic_decoder import EllipsoidDecoder
    from fake_world import write_sdf

    from ushape.data.layout import WorldIndex
    from ushape.evaluation.protocols import EncoderSpec
    from ushape.evaluation.uncertainty_protocol import sdf_rows
    from ushape.evaluation.views import Encodings, ViewKey

    world = WorldIndex(tmp_path, category="", splits={})
    points = np.random.default_rng(0).uniform(-0.8, 0.8, (300, 3))
    write_sdf(world, "s", np.concatenate([points, np.linalg.norm(points, axis=1, keepdims=True) - 0.55], 1))
    encodings = Encodings([ViewKey("s", 0)], torch.zeros(1, 3), torch.full((1, 3), 0.04))
    spec = EncoderSpec("es", "Ours", probabilistic=True)

    def rows(sdf_temperature):
        found, _ = sdf_rows(
            spec, encodings, EllipsoidDecoder(), world, 300, methods=("linearised",), sdf_temperature=sdf_temperature
        )
        return {row["variance"]: row for row in found}

    plain, scaled = rows(None), rows(4.0)
    assert scaled["equal"] == plain["equal"]  # the equal-variance baseline is no prediction: left alone
    assert scaled["predicted"]["calibration_error"] != plain["predicted"]["calibration_error"]
    # the same call twice, and T = 1 multiplies the variance by 1.0 exactly
    assert scaled["predicted"] == rows(4.0)["predicted"] and rows(1.0)["predicted"] == plain["predicted"]
