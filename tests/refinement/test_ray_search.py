"""Ray minimum search: the SDF grid's interpolation, and the grid search against the exact one on a sphere."""

from dataclasses import replace

import pytest
import torch

from ushape.data.cameras import look_at
from ushape.data.rendering import pixel_rays
from ushape.refinement.observation import ObservationSettings
from ushape.refinement.ray_search import ray_ball, ray_minimum, sdf_grid

RADIUS = 0.4


def linear_sdf(points):  # [P, 3] -> [P]: trilinear interpolation reproduces it exactly
    return points @ torch.tensor([0.3, -0.7, 1.1]) + 0.05


def test_grid_reads_a_linear_function_exactly_along_each_axis():
    grid = sdf_grid(linear_sdf, 17, 1.0)
    points = torch.rand(500, 3) * 1.6 - 0.8
    points = points[points.norm(dim=-1) <= 1.0]
    assert torch.allclose(grid(points), linear_sdf(points), atol=1e-5)


def test_grid_queries_only_the_nodes_the_ball_can_interpolate():
    asked = []

    def counting(points):
        asked.append(points)
        return linear_sdf(points)

    nodes = 17
    sdf_grid(counting, nodes, 1.0)
    points = torch.cat(asked)
    cell = 2.0 / (nodes - 1)
    assert points.norm(dim=-1).max() <= 1.0 + 3**0.5 * cell + 1e-6
    assert points.shape[0] < 0.75 * nodes**3  # the cube's corners are left out


def test_too_few_nodes_is_refused():
    with pytest.raises(ValueError, match="at least 2 nodes"):
        sdf_grid(linear_sdf, 1, 1.0)


def sphere_rays():
    K, w2c = look_at(30.0, 20.0, 2.0, 40.0, 48)
    o, d = pixel_rays(K, w2c, (48, 48))
    return torch.as_tensor(o, dtype=torch.float32), torch.as_tensor(d, dtype=torch.float32)


def line_distance(o, d):  # distance of each ray's line to the origin [R]
    t = -(o * d).sum(-1) / (d * d).sum(-1)
    return (o + t[:, None] * d).norm(dim=-1)


def test_grid_search_finds_the_sphere_minimum_and_skips_the_decoder_far_from_it():
    """min over a ray of |x| - r is its line's distance to the centre minus r (the closest point lies inside the
    unit ball). Near the surface the grid search is as exact as the decoder search; far from it, it asks the
    decoder nothing and is off by no more than its slack."""
    o, d = sphere_rays()
    near, far = ray_ball(o, d, 1.0)
    o, d = o[far > near], d[far > near]
    truth = line_distance(o, d) - RADIUS
    queried = []

    def sphere(points):
        queried.append(points.shape[0])
        return points.norm(dim=-1) - RADIUS

    exact, _ = ray_minimum(sphere, o, d, 24, 8, 1.0)
    decoder_queries = sum(queried)
    queried.clear()
    grid = sdf_grid(sphere, 33, 1.0)
    grid_queries = sum(queried)
    margin = 0.12
    found, points = ray_minimum(sphere, o, d, 24, 8, 1.0, grid=grid, margin=margin)
    band = truth.abs() < 0.07
    assert band.sum() > 50
    assert (found[band] - truth[band]).abs().max() < 2e-3
    assert (exact[band] - truth[band]).abs().max() < 2e-3
    far_rays = found >= margin
    at = points.norm(dim=-1) - RADIUS  # the point is where the minimum is (exactly, where the decoder was asked)
    assert torch.allclose(at[~far_rays], found[~far_rays], atol=1e-5)
    assert (at[far_rays] - found[far_rays]).abs().max() < 0.05
    assert far_rays.sum() > 0.3 * len(found)
    assert (found[far_rays] - truth[far_rays]).abs().max() < 0.05
    assert sum(queried) - grid_queries == 9 * int((~far_rays).sum())  # 1 + fine samples, only on near rays
    assert decoder_queries == 33 * len(o)


def test_a_ray_segment_cut_short_reads_only_the_part_in_front():
    o, d = sphere_rays()
    near, far = ray_ball(o, d, 1.0)
    keep = (far > near) & ((line_distance(o, d) - RADIUS) < -0.1)  # rays through the sphere's middle
    o, d, near = o[keep], d[keep], near[keep]

    def sphere(points):
        return points.norm(dim=-1) - RADIUS

    grid = sdf_grid(sphere, 33, 1.0)
    limit = near + 0.2  # a short segment from the ball's entry: the sphere (radius 0.4) is not reached
    found, _ = ray_minimum(sphere, o, d, 24, 8, 1.0, far_limit=limit, grid=grid, margin=0.12)
    entry = o + near[:, None] * d
    end = o + limit[:, None] * d
    assert (found > 0).all()
    assert (found >= torch.minimum(entry.norm(dim=-1), end.norm(dim=-1)) - RADIUS - 0.05).all()


def test_node_points_are_where_the_grid_stored_their_values():
    grid = sdf_grid(linear_sdf, 9, 1.0)
    flat = torch.arange(grid.volume.numel())
    inside = grid.volume.reshape(-1) < 4.0  # the nodes the ball can interpolate hold the function's value
    assert torch.allclose(grid.volume.reshape(-1)[inside], linear_sdf(grid.nodes(flat[inside])), atol=1e-6)


def test_a_grid_of_a_nearby_code_needs_its_drift_to_find_the_surface():
    """The grid of a sphere of radius 0.4 read for one of radius 0.55 (a code whose SDF moved by 0.15): a ray
    passing 0.5 from the centre meets the new sphere, but its stale minimum is 0.1 above the old one, past the
    margin of 0.08; with the drift given, the margin widens and the decoder's exact samples find the surface."""
    grown = 0.55

    def new_sphere(points):
        return points.norm(dim=-1) - grown

    stale = sdf_grid(lambda p: p.norm(dim=-1) - RADIUS, 33, 1.0)
    o = torch.tensor([[0.5, 0.0, -2.0], [0.0, 0.5, -2.0]])
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    truth = 0.5 - grown
    blind, _ = ray_minimum(new_sphere, o, d, 24, 8, 1.0, grid=stale, margin=0.08)
    assert (blind - (0.5 - RADIUS)).abs().max() < 0.01  # the stale value: the ray is taken for a miss
    drifted = replace(stale, drift=0.15)
    settings = ObservationSettings(tau=0.01, band=3.0, grid_slack=0.05)  # margin 0.08, + 2 x drift
    found, _ = settings.minimum(new_sphere, o, d, None, drifted)
    assert (found - truth).abs().max() < 5e-3
