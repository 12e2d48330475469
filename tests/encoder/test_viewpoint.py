"""The camera-azimuth head (ushape.encoder.viewpoint): its labels' geometry, that it learns an azimuth the features
carry, and that it refuses what it cannot fit."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ushape.data.cameras import look_at
from ushape.encoder.viewpoint import (
    angular_difference,
    camera_azimuth_elevation,
    fit_viewpoint_head,
    load_viewpoint_head,
    save_viewpoint_head,
    viewpoint_scores,
)


@pytest.mark.parametrize("azimuth, elevation", [(0.0, 25.0), (95.0, 30.0), (271.0, 10.0)])
def test_a_look_at_cameras_azimuth_and_elevation_are_read_back(azimuth, elevation):
    _, w2c = look_at(azimuth, elevation, 2.0, 49.13, 64)
    az, el = camera_azimuth_elevation(w2c)
    assert float(angular_difference(torch.tensor(az), torch.tensor(azimuth))) < 1e-6
    assert el == pytest.approx(elevation)


def features_of(azimuths: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """Features that carry the azimuth (its cosine and sine, mixed into 32 noisy dimensions)."""
    rad = torch.deg2rad(azimuths)
    signal = torch.stack([torch.cos(rad), torch.sin(rad)], 1)
    mixing = torch.randn(2, 32, generator=torch.Generator().manual_seed(7))
    return signal @ mixing + 0.05 * torch.randn(azimuths.shape[0], 32, generator=generator)


def test_the_head_learns_an_azimuth_the_features_carry(tmp_path):
    g = torch.Generator().manual_seed(0)
    train = torch.rand(2000, generator=g) * 360
    held = torch.rand(300, generator=g) * 360
    head = fit_viewpoint_head(features_of(train, g), train, bins=24, epochs=20)
    scores = viewpoint_scores(head, features_of(held, g), held)
    assert scores["median_error_deg"] < 10.0 and scores["within_15"] > 0.8 and scores["flipped"] < 0.02
    save_viewpoint_head(head, tmp_path / "viewpoint.pt", scores)
    again = load_viewpoint_head(tmp_path / "viewpoint.pt")
    x = features_of(held[:5], g)
    # stored in fp16: the log-probabilities move by rounding only (< 0.01 nats), so the reloaded head's most likely
    # bin is, under the original head, within that tolerance of the original's best (a near-tie may swap them)
    before, after = head.log_probs(x), again.log_probs(x)
    torch.testing.assert_close(after, before, atol=1e-2, rtol=0)
    chosen = before.gather(1, after.argmax(-1, keepdim=True))[:, 0]
    assert bool((before.max(-1).values - chosen <= 2e-2).all())
    # noise features: the head cannot know, and says so by spreading its probability
    blind = fit_viewpoint_head(torch.randn(2000, 32, generator=g), train, bins=24, epochs=5)
    assert float(blind.log_probs(x).exp().max()) < 0.5
    assert math.isclose(float(head.log_probs(x).exp().sum(-1).mean()), 1.0, rel_tol=1e-6)


def test_too_few_views_are_refused():
    with pytest.raises(ValueError, match="N >= 24"):
        fit_viewpoint_head(torch.zeros(10, 4), torch.zeros(10))
    assert np.isfinite(float(angular_difference(torch.tensor(359.0), torch.tensor(1.0))))
