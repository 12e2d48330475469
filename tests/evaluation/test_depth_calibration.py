"""Depth-std calibration (Table D): known answers for the scores, and a sphere whose predicted radius is drawn
from the predicted Gaussian (calibrated by construction) against one whose variance is four times too small."""

import numpy as np
import pytest
import torch
import trimesh

from ushape.data.cameras import look_at
from ushape.data.rendering import render_mesh
from ushape.evaluation.depth_calibration import DepthTarget, depth_calibration, view_depth_errors

SIZE, DISTANCE, RADIUS, SIGMA = 9, 2.5, 0.5, 0.02


class RadiusDecoder(torch.nn.Module):
    """|x| - z_0: a sphere whose radius is the code."""

    latent_size = 1

    def forward(self, xyz, z):
        return xyz.norm(dim=-1) - z[..., 0]


def test_scores_of_standard_normal_errors():
    generator = torch.Generator().manual_seed(0)
    std = 0.5 + torch.rand(20000, generator=generator, dtype=torch.float64)
    error = std * torch.randn(20000, generator=generator, dtype=torch.float64)
    scores, (p, freq) = depth_calibration(error, std, n_levels=10)
    assert scores["coverage_68"] == pytest.approx(0.68, abs=0.01)
    assert scores["coverage_95"] == pytest.approx(0.95, abs=0.005)
    assert scores["calibration_error"] < 0.01 and abs(scores["mean_z"]) < 0.02
    assert scores["rms_z"] == pytest.approx(1, abs=0.02)
    assert scores["median_abs_z"] == pytest.approx(0.674, abs=0.02)
    assert scores["rank_corr"] > 0.1  # a larger std comes with a larger error
    assert scores["mean_std"] == pytest.approx(float(std.mean())) and scores["n_pixels"] == 20000
    assert scores["mean_abs_error"] == pytest.approx(float(error.abs().mean()))
    assert len(p) == len(freq) == 10
    over, _ = depth_calibration(error, 2 * std)  # twice the std: too sure of nothing, too many inside
    assert over["coverage_68"] > 0.9 and over["rms_z"] == pytest.approx(0.5, abs=0.01)
    exact, _ = depth_calibration(torch.tensor([0.0, 1.0]), torch.tensor([0.0, 0.0]))
    assert exact["coverage_68"] == 0.5 and np.isnan(exact["mean_z"])  # std 0: inside only when exact
    with pytest.raises(ValueError, match="one sigma per error"):
        depth_calibration(torch.zeros(3), torch.ones(2))
    with pytest.raises(ValueError, match="empty"):
        depth_calibration(torch.zeros(0), torch.zeros(0))


@pytest.fixture(scope="module")
def sphere_truth():
    """The true depth [SIZE, SIZE] of a radius-0.5 sphere mesh, and the camera it was rendered with."""
    K, w2c = look_at(20.0, 10.0, DISTANCE, 30.0, SIZE)
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=RADIUS)
    return render_mesh(sphere, K, w2c, SIZE)["depth"], K, w2c


@pytest.mark.parametrize("method", ["implicit", "mc"])
def test_a_prediction_drawn_from_its_own_gaussian_is_calibrated(sphere_truth, method):
    depth, K, w2c = sphere_truth
    # true radii at the normal quantiles of the prediction: N(0, 1) z-scores without sampling noise
    radii = RADIUS + SIGMA * torch.special.ndtri((torch.arange(60, dtype=torch.float64) + 0.5) / 60).float()
    pools = {"right": [], "overconfident": []}
    for i, r in enumerate(radii):
        for name, var in (("right", SIGMA**2), ("overconfident", SIGMA**2 / 4)):
            target = DepthTarget(r[None], torch.tensor([var]), depth, K, w2c)
            pools[name].append(view_depth_errors(RadiusDecoder(), target, method, n_codes=20, steps=40, seed=i))
    scores = {name: depth_calibration(*(torch.cat(t) for t in zip(*parts)))[0] for name, parts in pools.items()}
    right, over = scores["right"], scores["overconfident"]
    # The truth's z-score per view is (r - 0.5) / sigma times a per-pixel factor near 1 (first order): N(0, 1).
    # MC's std from M = 20 codes is off by ~16 % per view, which spreads its z-scores a little.
    tolerance = 0.03 if method == "implicit" else 0.08
    assert right["coverage_68"] == pytest.approx(0.68, abs=tolerance)
    assert right["coverage_95"] == pytest.approx(0.95, abs=tolerance)
    assert right["calibration_error"] < tolerance and right["rms_z"] == pytest.approx(1.0, abs=0.15)
    # the same means (MC's: up to its codes' average, which depends on the variance drawn from)
    assert right["mean_abs_error"] == pytest.approx(over["mean_abs_error"], rel=1e-6 if method == "implicit" else 0.1)
    # half the std: the 68 % interval holds about P(|Z| <= 0.5) = 38 %
    assert over["coverage_68"] < 0.5 and over["rms_z"] > 1.6 and over["calibration_error"] > 0.15
    assert right["n_pixels"] > 60 * 20


def test_view_depth_errors_at_the_centre_pixel(sphere_truth):
    depth, K, w2c = sphere_truth
    target = DepthTarget(torch.tensor([0.53]), torch.tensor([1e-4]), depth, K, w2c)
    error, std = view_depth_errors(RadiusDecoder(), target, "implicit", steps=60)
    centre = SIZE // 2 * SIZE + SIZE // 2  # the pixel whose ray passes through the centre: first hit, row-major
    hits = np.flatnonzero(depth.reshape(-1) > 0)
    i = int(np.searchsorted(hits, centre))
    # true depth d - 0.5, predicted d - 0.53: error +0.03, std = sigma_r = 0.01 head-on
    assert float(error[i]) == pytest.approx(0.03, abs=2e-3) and float(std[i]) == pytest.approx(0.01, rel=0.02)
    assert (error > 0).all()
