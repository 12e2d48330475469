"""Sphere tracing known answers on an analytic sphere."""

import math

import numpy as np
import torch

from ushape.data.cameras import look_at
from ushape.propagation.monte_carlo import sample_codes
from ushape.propagation.sphere_tracing import depth_uncertainty, ray_box, sphere_trace


class SphereDecoder(torch.nn.Module):
    """SDF of a sphere whose radius is the code's first entry: |x| - z[0]."""

    def forward(self, xyz, z):
        return xyz.norm(dim=-1) - z[..., 0]


def test_ray_box_entry_and_exit():
    near, far = ray_box(torch.tensor([[-3.0, 0, 0], [-3.0, 5, 0]]), torch.tensor([[1.0, 0, 0], [1.0, 0, 0]]), 1.0)
    assert torch.allclose(near[0], torch.tensor(2.0)) and torch.allclose(far[0], torch.tensor(4.0))
    assert far[1] < near[1]


def test_sphere_trace_hits_at_distance_minus_radius():
    origins = torch.tensor([[0.0, 0.0, -2.5]])
    directions = torch.tensor([[0.0, 0.0, 2.0]])  # not unit: t is along d
    radii = torch.tensor([0.5, 0.7])
    t, hit = sphere_trace(lambda p, m: p.norm(dim=-1) - radii[m], origins, directions, 2, eps=1e-5)
    assert hit.all()
    assert torch.allclose(t[:, 0] * 2.0, 2.5 - radii, atol=1e-4)


def test_depth_at_centre_is_distance_minus_radius_and_std_zero_for_equal_codes():
    size, distance, radius = 33, 2.5, 0.6
    K, w2c = look_at(30.0, 20.0, distance, 40.0, size)
    codes = torch.full((4, 3), radius)
    stats = depth_uncertainty(SphereDecoder(), codes, K, w2c, (size, size), steps=60, eps=1e-5)
    centre = stats.mean[size // 2, size // 2]
    # the centre pixel's ray passes within a fraction of a pixel of the sphere's centre
    assert abs(float(centre) - (distance - radius)) < 2e-3
    hits = stats.hit_rate > 0
    # Equal codes, one depth: the std is 0 up to float32 rounding (equal rows of one batch may still take
    # different kernel paths, e.g. a vector loop and its tail, which may round a norm's last bit differently).
    assert float(stats.std[hits].max()) <= 1e-6 and torch.all(stats.hit_rate[hits] == 1)
    assert torch.isnan(stats.mean[0, 0]) and stats.hit_rate[0, 0] == 0  # corner ray misses
    # the silhouette's area matches the projected disc: radius_px = f * r / sqrt(d^2 - r^2)
    expected = math.pi * (K[0, 0] * radius / math.sqrt(distance**2 - radius**2)) ** 2
    assert abs(int(hits.sum()) - expected) / expected < 0.06


def test_depth_spread_follows_the_radius_spread():
    size, distance = 17, 3.0
    K, w2c = look_at(0.0, 0.0, distance, 30.0, size)
    codes = sample_codes(torch.tensor([0.5, 0.0]), torch.tensor([0.01, 0.0]), 400, torch.Generator().manual_seed(0))
    stats = depth_uncertainty(SphereDecoder(), codes, K, w2c, (size, size), steps=60, eps=1e-5)
    # at the centre depth = distance - radius, so its std is the radius std, 0.1
    assert abs(float(stats.std[size // 2, size // 2]) - 0.1) < 0.012
    assert np.isclose(float(stats.mean[size // 2, size // 2]), distance - 0.5, atol=0.015)
