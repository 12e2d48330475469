"""Refinement known answers: a sphere whose radius is linear in the code, r = r0 + c . z, seen by calibrated views.

Its silhouette and depth are analytic in z, so the MAP code and the Laplace covariance
(Sigma^-1 + J^T W J)^-1 are known; code dimensions the radius ignores keep the prior variance.
"""

import dataclasses

import numpy as np
import pytest
import torch
from torch import nn

from ushape.data.cameras import look_at
from ushape.data.rendering import pixel_rays
from ushape.refinement import ObservationSettings, ObservedView, RefineSettings, crop_view, refine, residuals
from ushape.refinement.observation import view_rays, with_jacobian
from ushape.refinement.ray_search import ray_ball

R0, C = 0.35, torch.tensor([0.1, 0.05, 0.0, 0.0], dtype=torch.float64)
Z_TRUE = torch.tensor([1.0, -0.6, 0.4, -0.2], dtype=torch.float64)
SIZE, TAU = 32, 0.02


class SphereDecoder(nn.Module):
    """sdf(x, z) = |x| - (r0 + c . z): an exact SDF; dimensions where c is 0 are seen by no view."""

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("c", C.float())

    def forward(self, xyz, z):
        return xyz.norm(dim=-1) - (R0 + (z * self.c).sum(-1))


def radius(z):
    return R0 + float(C @ z.double())


def rays(K, w2c):
    o, d = pixel_rays(K, w2c, (SIZE, SIZE))
    return torch.as_tensor(o, dtype=torch.float64), torch.as_tensor(d, dtype=torch.float64)


def closest_distance(o, d):
    """Distance of each ray's line to the origin [P] (the sphere's centre)."""
    t = -(o * d).sum(-1) / (d * d).sum(-1)
    return (o + t[:, None] * d).norm(dim=-1)


def sphere_depth(o, d, r):
    """Camera-z depth of the first hit of |x| = r [P] (0 = miss) and the discriminant [P]."""
    a, b = (d * d).sum(-1), (o * d).sum(-1)
    disc = b * b - a * ((o * o).sum(-1) - r * r)
    t = (-b - disc.clamp_min(0).sqrt()) / a
    return torch.where(disc > 0, t, torch.zeros_like(t)), disc


def cameras(n):
    return [look_at(360.0 * i / n + 10.0, 20.0, 2.0, 40.0, SIZE) for i in range(n)]


def sphere_view(K, w2c, r, soft=True):
    o, d = rays(K, w2c)
    rho = closest_distance(o, d)
    mask = torch.sigmoid((r - rho) / TAU) if soft else (rho < r).double()
    depth, _ = sphere_depth(o, d, r)
    return ObservedView(K, w2c, mask.float().reshape(SIZE, SIZE), depth.float().reshape(SIZE, SIZE))


OBS = ObservationSettings(tau=TAU, size=SIZE, coarse=64, fine=16, trace_steps=60, trace_eps=1e-5)


def test_masks_recover_the_radius_and_the_analytic_laplace_covariance():
    decoder = SphereDecoder()
    views = [sphere_view(K, w2c, radius(Z_TRUE)) for K, w2c in cameras(3)]
    mu, var = torch.zeros(4), torch.ones(4)
    settings = RefineSettings(mode="masks", sigma_mask=0.05, observation=OBS, iterations=30)
    post = refine(decoder, mu, var, views, settings)
    assert post.fallback is None
    assert radius(post.mu) == pytest.approx(radius(Z_TRUE), abs=2e-3)
    # The prior N(0, I) and one constrained direction c: the MAP is the minimum-norm code of that radius.
    expected = C * (radius(Z_TRUE) - R0) / (C @ C)
    assert torch.allclose(post.mu.double(), expected, atol=2e-2)
    # Analytic J rows: dp/dz = p (1 - p) / tau c with p = sigmoid((r* - rho) / tau).
    jtj = 0.0
    for K, w2c in cameras(3):
        rho = closest_distance(*rays(K, w2c))
        p = torch.sigmoid((radius(post.mu) - rho) / TAU)
        jtj += float(((p * (1 - p) / TAU) ** 2).sum()) / settings.sigma_mask**2
    analytic = torch.linalg.inv(torch.eye(4, dtype=torch.float64) + jtj * torch.outer(C, C))
    assert torch.allclose(post.cov.double(), analytic, rtol=0.05, atol=2e-4)
    assert float(C @ post.cov.double() @ C) < 0.01 * float(C @ C)  # the seen direction shrinks
    assert post.cov[0, 1] < 0  # full covariance: one radius, two dimensions that trade off
    assert torch.allclose(post.cov[2:, 2:], torch.eye(2))  # dimensions no view sees keep the prior
    assert torch.allclose(post.cov[:2, 2:], torch.zeros(2, 2))


def test_surface_depth_recovers_the_radius_and_the_analytic_laplace_covariance():
    decoder = SphereDecoder()
    views = [sphere_view(K, w2c, radius(Z_TRUE)) for K, w2c in cameras(2)]
    settings = RefineSettings(mode="depth", sigma_mask=1e4, sigma_depth=0.01, observation=OBS)
    mu, var = torch.zeros(4), torch.tensor([1.0, 1.0, 0.5, 2.0])
    post = refine(decoder, mu, var, views, settings)
    assert post.fallback is None
    assert radius(post.mu) == pytest.approx(radius(Z_TRUE), abs=1e-4)
    # r = |x_obs| - r(z) at every back-projected return: dr/dz = -c on each, N returns.
    returns = sum(int((v.depth > 0).sum()) for v in views)
    assert post.rows["depth"] == returns
    precision = torch.diag(1.0 / var.double())
    analytic = torch.linalg.inv(precision + returns / settings.sigma_depth**2 * torch.outer(C, C))
    assert torch.allclose(post.cov.double(), analytic, rtol=1e-3, atol=1e-9)
    assert post.cov[2, 2] == pytest.approx(0.5) and post.cov[3, 3] == pytest.approx(2.0)


def test_traced_depth_recovers_the_radius_and_the_analytic_laplace_covariance():
    decoder = SphereDecoder()
    views = [sphere_view(K, w2c, radius(Z_TRUE)) for K, w2c in cameras(2)]
    traced = dataclasses.replace(OBS, depth_residual="trace")
    settings = RefineSettings(mode="depth", sigma_mask=1e4, sigma_depth=0.01, observation=traced)
    mu, var = torch.zeros(4), torch.tensor([1.0, 1.0, 0.5, 2.0])
    post = refine(decoder, mu, var, views, settings)
    assert post.fallback is None and post.rows["depth"] > 100
    assert radius(post.mu) == pytest.approx(radius(Z_TRUE), abs=1e-4)
    # Analytic dt/dz = -r / sqrt(disc) c on every ray that hits the sphere and has a depth return.
    jtj = 0.0
    for K, w2c in cameras(2):
        o, d = rays(K, w2c)
        _, disc = sphere_depth(o, d, radius(post.mu))
        hit = disc > 1e-3  # the trace converges on all but grazing rays
        jtj += float((radius(post.mu) ** 2 / disc[hit]).sum()) / settings.sigma_depth**2
    precision = torch.diag(1.0 / var.double())
    analytic = torch.linalg.inv(precision + jtj * torch.outer(C, C))
    assert torch.allclose(post.cov.double(), analytic, rtol=0.05, atol=1e-6)
    assert post.cov[2, 2] == pytest.approx(0.5) and post.cov[3, 3] == pytest.approx(2.0)


def test_a_full_prior_covariance_is_accepted_and_kept_on_unseen_dimensions():
    decoder = SphereDecoder()
    views = [sphere_view(K, w2c, radius(Z_TRUE)) for K, w2c in cameras(1)]
    prior = torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.3], [0.0, 0.0, 0.3, 0.5]])
    post = refine(decoder, torch.zeros(4), prior, views, RefineSettings(sigma_mask=0.1, observation=OBS))
    assert post.fallback is None
    assert torch.allclose(post.cov[2:, 2:], prior[2:, 2:], atol=1e-5)


def test_unobserved_pixels_carry_no_likelihood_and_are_not_background():
    decoder = SphereDecoder()
    K, w2c = cameras(1)[0]
    full = sphere_view(K, w2c, radius(Z_TRUE), soft=False)
    # A truncated photo: the box runs past the image's bottom and right edges.
    box = (SIZE // 2, SIZE // 2, SIZE, SIZE)
    cut = crop_view(full, box, (SIZE, SIZE))
    assert int(cut.observed.sum()) == (SIZE // 2) ** 2
    res = residuals(decoder, Z_TRUE.float(), [cut], OBS, use_depth=False)
    assert res.r.shape[0] == (SIZE // 2) ** 2
    # The crop keeps the camera: each cropped pixel's ray is the original pixel's ray.
    o_full, d_full, _ = view_rays(full, OBS)
    o_cut, d_cut, pixels = view_rays(cut, OBS)
    rows, cols = pixels // SIZE, pixels % SIZE
    source = (rows + SIZE // 2) * SIZE + (cols + SIZE // 2)
    assert torch.allclose(d_cut, d_full[source], atol=1e-5) and torch.allclose(o_cut, o_full[source])
    # Only a quarter of the sphere is in view, yet its radius is recovered: the rest is not read as empty.
    settings = RefineSettings(sigma_mask=0.1, observation=OBS, iterations=30)
    post = refine(decoder, torch.zeros(4), torch.ones(4), [cut], settings)
    assert radius(post.mu) == pytest.approx(radius(Z_TRUE), abs=0.02)


class NaNDecoder(SphereDecoder):
    def forward(self, xyz, z):
        return super().forward(xyz, z) * float("nan")


def test_empty_masks_no_cameras_and_nan_fall_back_to_the_prior(caplog):
    K, w2c = cameras(1)[0]
    empty = ObservedView(K, w2c, torch.zeros(SIZE, SIZE))
    mu, var = torch.full((4,), 0.5), torch.full((4,), 0.2)
    for decoder, views, reason in [
        (SphereDecoder(), [empty], "empty"),
        (SphereDecoder(), [None, None], "camera"),
        (NaNDecoder(), [sphere_view(K, w2c, 0.4)], "non-finite"),
    ]:
        post = refine(decoder, mu, var, views, RefineSettings(observation=OBS))
        assert reason in post.fallback
        assert torch.equal(post.mu, mu) and torch.equal(post.cov, torch.diag(var))
    assert "fell back" in caplog.text and "no camera" in caplog.text


def test_bad_inputs_say_what_to_pass():
    K, w2c = cameras(1)[0]
    view = ObservedView(K, w2c, torch.ones(SIZE, SIZE), depth=torch.ones(4, 4))
    with pytest.raises(ValueError, match="depth must have the mask's shape"):
        refine(SphereDecoder(), torch.zeros(4), torch.ones(4), [view])
    with pytest.raises(ValueError, match="refine mode"):
        refine(SphereDecoder(), torch.zeros(4), torch.ones(4), [view], RefineSettings(mode="photo"))


def test_free_space_rows_see_matter_in_front_of_the_depth_returns_and_their_jacobian_is_exact():
    decoder = SphereDecoder()
    K, w2c = cameras(1)[0]
    view = sphere_view(K, w2c, radius(Z_TRUE))
    obs = dataclasses.replace(OBS, free_margin=0.03)
    returns = int((view.depth > 0).sum())
    at_truth = residuals(decoder, Z_TRUE.float(), [view], obs, use_depth=True)
    free = at_truth.kind == 2
    assert int(free.sum()) == returns
    # The true sphere leaves the segment in front of each return empty, even where the surface is slanted.
    assert torch.all(at_truth.r[free] == 0) and torch.all(at_truth.J[free] == 0)
    # A sphere 0.08 larger puts matter in front of every return: r = the segment's minimum SDF, at the
    # segment's end, 0.03 cos(slant) - 0.08: -0.05 on the central ray, down to -0.08 at grazing rays.
    bigger = Z_TRUE.clone()
    bigger[0] += 0.8
    grown = residuals(decoder, bigger.float(), [view], obs, use_depth=True)
    r = grown.r[grown.kind == 2]
    assert float(r.max()) == pytest.approx(-0.05, abs=2e-3) and float(r.min()) > -0.08
    # dr/dz = ds/dz at the segment's minimum = -c on every row that sees matter.
    inside = (grown.kind == 2) & (grown.r < 0)
    assert int(inside.sum()) > 10
    assert torch.allclose(grown.J[inside], -C.float().expand(int(inside.sum()), -1), atol=1e-6)


class CountingSphere(SphereDecoder):
    """The sphere, counting the gradient passes (forwards with a code that requires grad)."""

    def __init__(self) -> None:
        super().__init__()
        self.gradient_passes = 0

    def forward(self, xyz, z):
        self.gradient_passes += int(z.requires_grad)
        return super().forward(xyz, z)


@pytest.mark.parametrize("depth_residual", ["surface", "trace"])
def test_deferred_jacobian_equals_the_eager_one_and_rejected_trials_pay_no_gradient(depth_residual, monkeypatch):
    K, w2c = cameras(1)[0]
    view = sphere_view(K, w2c, radius(Z_TRUE))
    obs = dataclasses.replace(OBS, free_margin=0.03, depth_residual=depth_residual)
    bigger = Z_TRUE.clone()
    bigger[0] += 0.8  # matter in front of the returns: every kind of row has a Jacobian
    decoder = CountingSphere()
    eager = residuals(decoder, bigger.float(), [view], obs, use_depth=True)
    lazy = residuals(decoder, bigger.float(), [view], obs, use_depth=True, jacobian=False)
    # Exact: residuals(jacobian=True) is with_jacobian of this very result, the same calls on the same points.
    assert lazy.J.shape == (0, 4) and torch.equal(lazy.r, eager.r) and torch.equal(lazy.kind, eager.kind)
    decoder.gradient_passes = 0
    filled = with_jacobian(decoder, bigger.float(), lazy)
    assert decoder.gradient_passes == 1 and torch.equal(filled.J, eager.J)
    assert {int(k) for k in eager.kind[eager.J.abs().sum(1) > 0]} == {0, 1, 2}
    # The LM asks for gradients at its start and once per step it takes, never at a trial it rejects: an
    # undamped start from far away overshoots, so some trials are rejected.
    evaluations = []
    counted = lambda *a, **k: evaluations.append(1) or residuals(*a, **k)  # noqa: E731
    monkeypatch.setattr("ushape.refinement.posterior.residuals", counted)
    decoder.gradient_passes = 0
    settings = RefineSettings(mode="depth", damping=1e-12, tolerance=1e-9, observation=obs)
    post = refine(decoder, 3 * torch.ones(4), torch.ones(4), [view], settings)
    assert decoder.gradient_passes <= post.iterations + 1 < len(evaluations)


class FloaterDecoder(SphereDecoder):
    """The sphere, and a floating ball of radius 0.05 + 0.1 z[2] at `centre` (none where that is negative)."""

    def __init__(self, centre) -> None:
        super().__init__()
        self.register_buffer("centre", torch.as_tensor(centre, dtype=torch.float32))

    def forward(self, xyz, z):
        floater = (xyz - self.centre).norm(dim=-1) - (0.05 + 0.1 * z[..., 2])
        return torch.minimum(super().forward(xyz, z), floater)


def test_free_space_removes_matter_that_neither_the_silhouette_nor_the_returns_see():
    K, w2c = cameras(1)[0]
    eye = -w2c[:3, :3].T @ w2c[:3, 3]
    decoder = FloaterDecoder(0.7 * eye / np.linalg.norm(eye))  # between the camera and the sphere
    truth = Z_TRUE.clone()
    truth[2] = -1.0  # no floater: the view sees the sphere alone
    view = sphere_view(K, w2c, radius(truth))
    # The prior believes in a floater of radius 0.15; it hides inside the sphere's silhouette and
    # none of the returns lies on it, so masks and the surface term leave it where the prior put it.
    mu, var = torch.tensor([1.0, -0.6, 1.0, 0.0]), torch.tensor([0.01, 0.01, 1.0, 1.0])
    settings = RefineSettings(mode="depth", sigma_depth=0.02, iterations=10, tau_schedule=(1.0,))
    no_free = dataclasses.replace(OBS, free_margin=0.0)
    kept = refine(decoder, mu, var, [view], dataclasses.replace(settings, observation=no_free))
    removed = refine(decoder, mu, var, [view], dataclasses.replace(settings, observation=OBS))
    assert removed.rows["free"] == removed.rows["depth"] > 100 and kept.rows["free"] == 0
    assert 0.05 + 0.1 * float(kept.mu[2]) > 0.14
    # Down to what the ray samples resolve (a step of ~0.025 along the segment), from 0.15.
    assert 0.05 + 0.1 * float(removed.mu[2]) < 0.03


def test_ray_ball_segments_are_the_chords_of_the_unit_ball():
    origins = torch.tensor([[0.0, 0.0, -3.0], [0.0, 0.5, -3.0], [0.0, 2.0, -3.0], [0.0, 0.0, 0.0]])
    directions = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    near, far = ray_ball(origins, directions, 1.0)
    assert torch.allclose(near[:2], torch.tensor([1.0, 3.0 - 0.75**0.5]))
    assert torch.allclose(far[:2], torch.tensor([2.0, 3.0 + 0.75**0.5]))
    assert far[2] < near[2]  # a miss
    assert near[3] == 0.0 and far[3] == pytest.approx(1.0)  # a ray that starts inside
