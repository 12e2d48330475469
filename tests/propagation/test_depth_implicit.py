"""Depth std by implicit differentiation: known answers (a tilted plane, a sphere) and agreement with Monte Carlo."""

import pytest
import torch

from ushape.data.cameras import R2N2_FOV_DEG, look_at
from ushape.data.rendering import pixel_rays
from ushape.decoder.network import DeepSDFDecoder
from ushape.decoder.query import frozen
from ushape.propagation.depth_implicit import (
    depth_sensitivity,
    depth_stats,
    depth_uncertainty_implicit,
    std_agreement,
)
from ushape.propagation.linearised import sdf_gradients
from ushape.propagation.monte_carlo import sample_codes
from ushape.propagation.sphere_tracing import DepthStats, depth_uncertainty

NORMAL = torch.tensor([1.0, 0.3, -0.2]) / torch.tensor([1.0, 0.3, -0.2]).norm()
OFFSET = 0.2
A = torch.tensor([0.1, -0.05, 0.2])
MU = torch.tensor([0.1, 0.2, -0.3])
VAR = torch.tensor([0.04, 0.09, 0.01])


class PlaneDecoder(torch.nn.Module):
    """s(x, z) = n.x - c - a.z: a plane whose offset is linear in z (a true SDF, |grad| = 1)."""

    latent_size = 3

    def forward(self, xyz, z):
        return xyz @ NORMAL - OFFSET - z @ A


class RadiusDecoder(torch.nn.Module):
    """s(x, z) = |x| - (0.5 + b.z): a sphere whose radius is linear in z."""

    latent_size = 2
    b = torch.tensor([1.0, 0.5])

    def forward(self, xyz, z):
        return xyz.norm(dim=-1) - (0.5 + z @ self.b)


def rays(K, w2c, size):
    origins, directions = pixel_rays(K, w2c, (size, size))
    return torch.as_tensor(origins, dtype=torch.float64), torch.as_tensor(directions, dtype=torch.float64)


def test_plane_depth_std_is_the_analytic_one_and_mc_agrees():
    size = 17
    K, w2c = look_at(0.0, 0.0, 3.0, 40.0, size)  # on +x, looking at the tilted plane's front
    origins, directions = rays(K, w2c, size)
    # n.(o + t d) = c + a.z  ->  t = (c + a.z - n.o) / (n.d): linear in z, std sqrt(sum a_k^2 var_k) / |n.d|
    n_dot_d = directions @ NORMAL.double()
    depth = ((OFFSET + A.double() @ MU.double() - origins @ NORMAL.double()) / n_dot_d).reshape(size, size)
    std = (torch.sqrt((A.double() ** 2 * VAR.double()).sum()) / n_dot_d.abs()).reshape(size, size)
    implicit = depth_uncertainty_implicit(PlaneDecoder(), MU, VAR, K, w2c, (size, size), steps=60, eps=1e-6)
    hit = implicit.hit_rate > 0
    assert hit.sum() > 100 and set(implicit.hit_rate.unique().tolist()) <= {0.0, 1.0}
    assert torch.allclose(implicit.mean[hit].double(), depth[hit], atol=1e-4)
    assert torch.allclose(implicit.std[hit].double(), std[hit], rtol=1e-4)
    assert torch.isnan(implicit.std[~hit]).all() and torch.isnan(implicit.mean[~hit]).all()
    codes = sample_codes(MU, VAR, 4000, torch.Generator().manual_seed(0))
    mc = depth_uncertainty(PlaneDecoder(), codes, K, w2c, (size, size), steps=60, eps=1e-6)
    every = (mc.hit_rate == 1) & hit
    assert every.sum() > 100
    # The std of a std estimated from M = 4000 draws is 1/sqrt(2M) = 1.1 %.
    assert torch.allclose(mc.std[every].double(), std[every], rtol=0.04)


def sphere_depth(origins, directions, radius):
    """First hit t of rays o + t d with the sphere |x| = radius, and sqrt of the discriminant (NaN: miss)."""
    od, dd, oo = (origins * directions).sum(-1), (directions**2).sum(-1), (origins**2).sum(-1)
    root = torch.sqrt(od**2 - dd * (oo - radius**2))
    return (-od - root) / dd, root


def test_sphere_depth_and_std_match_the_analytic_ones_and_mc():
    size, radius_std = 17, 0.01
    K, w2c = look_at(30.0, 20.0, 2.5, 40.0, size)
    origins, directions = rays(K, w2c, size)
    mu, var = torch.tensor([0.05, -0.02]), torch.tensor([0.6, 1.6]) * radius_std**2  # sum b_k^2 var_k = 0.01^2
    radius = 0.5 + float(RadiusDecoder.b @ mu)
    depth, root = sphere_depth(origins, directions, radius)
    # dt/dr = -r / sqrt(disc), so the first-order std is r sigma_r / sqrt(disc)
    std = (radius * radius_std / root).reshape(size, size)
    depth = depth.reshape(size, size)
    implicit = depth_uncertainty_implicit(RadiusDecoder(), mu, var, K, w2c, (size, size), steps=80, eps=1e-6)
    hit = implicit.hit_rate > 0
    assert torch.allclose(implicit.mean[hit].double(), depth[hit], atol=1e-4)
    # head-on (cosine of incidence > 0.3): the clamp is far away, so the std is the analytic one
    facing = (root / (directions.norm(dim=-1) * radius)).reshape(size, size) > 0.3
    assert (hit & facing).sum() > 50
    assert torch.allclose(implicit.std[hit & facing].double(), std[hit & facing], rtol=2e-3)
    # the grazing clamp caps the std at sigma_r / (min_cosine |d|) everywhere
    assert float(implicit.std[hit].max()) <= radius_std / 0.05 + 1e-6
    codes = sample_codes(mu, var, 1000, torch.Generator().manual_seed(1))
    mc = depth_uncertainty(RadiusDecoder(), codes, K, w2c, (size, size), steps=80, eps=1e-6)
    both = hit & (mc.hit_rate == 1) & facing
    ratio = implicit.std[both] / mc.std[both]
    assert abs(float(ratio.median()) - 1) < 0.03 and float((ratio - 1).abs().max()) < 0.06
    assert std_agreement(implicit, mc)["pixels"] >= int(both.sum())


def test_depth_sensitivity_known_answers_and_grazing_clamp():
    grad_z = torch.tensor([[2.0], [2.0]])
    grad_x = torch.tensor([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # head-on, and tangent to the ray
    directions = torch.tensor([[2.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    sensitivity = depth_sensitivity(grad_z, grad_x, directions, min_cosine=0.05)
    # head-on: ds/dt = -2, dt/dz = -2 / -2 = 1; tangent: ds/dt = 0 clamped to -0.05 |grad| |d|, dt/dz = 40
    assert torch.allclose(sensitivity, torch.tensor([[1.0], [40.0]]))


def sdf_like_decoder(seed: int) -> tuple[DeepSDFDecoder, torch.Tensor]:
    """conf/decoder/small.yaml's network with random weights, its output layer rescaled so the field has a
    median gradient of 1 (a random net's field is nearly flat: |grad| ~ 0.007) and about 20 % of the cube inside."""
    torch.manual_seed(seed)
    decoder = DeepSDFDecoder(64, [256] * 4, [2], dropout=0.0, weight_norm=True, output_tanh=True).eval()
    code, points = 0.1 * torch.randn(64), torch.rand(4096, 3) * 2 - 1
    last = decoder.layers[-1]
    with frozen(decoder):
        _, _, grad_x = sdf_gradients(decoder, code, points, with_xyz=True)
        with torch.no_grad():
            scale = grad_x.norm(dim=-1).median()
            last.weight /= scale
            last.bias /= scale
            last.bias -= torch.atanh(decoder(points, code).clamp(-0.999, 0.999)).quantile(0.2)
    return decoder, code


@pytest.fixture(scope="module")
def deepsdf_depths():
    """Implicit and MC (M = 100) depth stats of two views of a random small DeepSDF decoder, tiny var."""
    decoder, code = sdf_like_decoder(1)
    var, size = torch.full_like(code, 1e-6), 20
    codes = sample_codes(code, var, 100, torch.Generator().manual_seed(0))
    pairs = []
    for azimuth in (0.0, 120.0):
        K, w2c = look_at(azimuth, 27.5, 2.8, R2N2_FOV_DEG, size)
        pairs.append(
            (
                depth_uncertainty_implicit(decoder, code, var, K, w2c, (size, size), eps=1e-4),
                depth_uncertainty(decoder, codes, K, w2c, (size, size), eps=1e-4),
            )
        )
    return pairs


def pooled(pairs) -> tuple[DepthStats, DepthStats]:
    """The views' maps side by side, as one wide map per method."""
    join = lambda stats: DepthStats(*(torch.cat(m, dim=1) for m in zip(*stats)))  # noqa: E731
    return join([p[0] for p in pairs]), join([p[1] for p in pairs])


def test_implicit_agrees_with_mc_on_a_random_deepsdf_decoder(deepsdf_depths):
    implicit, mc = pooled(deepsdf_depths)
    agreement = std_agreement(implicit, mc)
    assert agreement["pixels"] >= 50
    # M = 100 codes: each MC std is within ~7 % (1/sqrt(2M)); a little curvature adds spread, not bias.
    # Ranks, not Pearson: at a pixel or two one of the 100 codes reaches another part (an MC std 6x the rest).
    assert 0.9 < agreement["median_ratio"] < 1.1 and agreement["spearman"] > 0.9
    hit = (implicit.hit_rate > 0) & (mc.hit_rate == 1)
    # the mean code's depth is the MC mean up to second order: well inside one std
    assert ((implicit.mean[hit] - mc.mean[hit]).abs() <= 0.5 * mc.std[hit]).all()
    # the same measure rejects a std 30 % too large and a std map with its pixels shuffled
    wrong = std_agreement(implicit._replace(std=1.3 * implicit.std), mc)
    assert not 0.9 < wrong["median_ratio"] < 1.1
    order = torch.randperm(implicit.std.numel(), generator=torch.Generator().manual_seed(0))
    shuffled = std_agreement(
        implicit._replace(
            std=implicit.std.flatten()[order].reshape(implicit.std.shape), hit_rate=torch.ones_like(implicit.hit_rate)
        ),
        mc,
    )
    assert not shuffled["spearman"] > 0.9


def test_depth_stats_dispatches_and_bad_input_is_a_value_error():
    K, w2c = look_at(0.0, 0.0, 3.0, 40.0, 9)
    mu, var = MU, VAR
    codes = sample_codes(mu, var, 3, torch.Generator().manual_seed(0))
    K2, w2c2 = look_at(30.0, 10.0, 3.0, 40.0, 9)
    implicit = depth_stats(PlaneDecoder(), mu, var, [(K, w2c), (K2, w2c2)], (9, 9), "implicit")
    mc = depth_stats(PlaneDecoder(), mu, var, [(K, w2c), (K2, w2c2)], (9, 9), "mc", codes)
    assert len(implicit) == len(mc) == 2 and implicit[1].mean.shape == mc[1].mean.shape == (9, 9)
    # Tracing both views together gives each view what tracing it alone does, up to float32 rounding: the
    # decoder's matrix products see other batches, so a ray ending within rounding of a threshold (|sdf| < eps,
    # the cube's edge) may flip its hit or take one more step (eps / |n.d| in depth). The other view's maps
    # would differ in 18 of the 81 hits and by 0.26 in median depth.
    alone = depth_uncertainty_implicit(PlaneDecoder(), mu, var, K2, w2c2, (9, 9))
    hit = (implicit[1].hit_rate > 0) & (alone.hit_rate > 0)
    assert int((implicit[1].hit_rate != alone.hit_rate).sum()) <= 1 and int(hit.sum()) > 40
    torch.testing.assert_close(implicit[1].mean[hit], alone.mean[hit], rtol=0, atol=1e-2)
    torch.testing.assert_close(implicit[1].std[hit], alone.std[hit], rtol=1e-5, atol=1e-8)
    assert torch.equal(implicit[1].mean.isnan(), implicit[1].hit_rate == 0)  # NaN where no hit, by construction
    with pytest.raises(ValueError, match="must be one of"):
        depth_stats(PlaneDecoder(), mu, var, [(K, w2c)], (9, 9), "linear")
    with pytest.raises(ValueError, match="pass codes"):
        depth_stats(PlaneDecoder(), mu, var, [(K, w2c)], (9, 9), "mc")
    with pytest.raises(ValueError, match="no cameras"):
        depth_stats(PlaneDecoder(), mu, var, [], (9, 9))
    with pytest.raises(ValueError, match="var must be >= 0"):
        depth_uncertainty_implicit(PlaneDecoder(), mu, -var, K, w2c, (9, 9))
    with pytest.raises(ValueError, match="the decoder takes 3"):
        depth_uncertainty_implicit(PlaneDecoder(), torch.zeros(4), torch.ones(4), K, w2c, (9, 9))
    with pytest.raises(ValueError, match="K \\[3, 3\\]"):
        depth_uncertainty_implicit(PlaneDecoder(), mu, var, K[:2], w2c, (9, 9))
    with pytest.raises(ValueError, match="steps"):
        depth_uncertainty_implicit(PlaneDecoder(), mu, var, K, w2c, (9, 9), steps=0)
    with pytest.raises(ValueError, match="min_cosine"):
        depth_uncertainty_implicit(PlaneDecoder(), mu, var, K, w2c, (9, 9), min_cosine=2.0)
    with pytest.raises(ValueError, match=r"\[M, D\]"):
        depth_uncertainty(PlaneDecoder(), mu, K, w2c, (9, 9))


# A full covariance over the plane's code: wide along two directions orthogonal to A, narrow along A, so the
# depth std (along A) is a fraction of what the variances on the diagonal alone would give.
B = torch.tensor([[0.2, 0.0], [0.0, 0.2], [-0.1, 0.05]])
COV = B @ B.T + 1e-3 * torch.eye(3)


def test_plane_depth_std_under_a_full_covariance_is_the_analytic_one_and_mc_agrees():
    size = 17
    K, w2c = look_at(0.0, 0.0, 3.0, 40.0, size)
    origins, directions = rays(K, w2c, size)
    n_dot_d = (directions @ NORMAL.double()).reshape(size, size)
    a = A.double()
    # t is linear in z with dt/dz = a / (n.d): std sqrt(a^T Sigma a) / |n.d|
    std = torch.sqrt(a @ COV.double() @ a) / n_dot_d.abs()
    diagonal_only = torch.sqrt((a**2 * COV.diagonal().double()).sum()) / n_dot_d.abs()
    assert float((diagonal_only / std).min()) > 4  # what reading only the diagonal would report
    implicit = depth_uncertainty_implicit(PlaneDecoder(), MU, COV, K, w2c, (size, size), steps=60, eps=1e-6)
    hit = implicit.hit_rate > 0
    assert hit.sum() > 100
    assert torch.allclose(implicit.std[hit].double(), std[hit], rtol=1e-4)
    codes = sample_codes(MU, COV, 4000, torch.Generator().manual_seed(0))
    mc = depth_uncertainty(PlaneDecoder(), codes, K, w2c, (size, size), steps=60, eps=1e-6)
    every = (mc.hit_rate == 1) & hit
    assert every.sum() > 100
    assert torch.allclose(mc.std[every].double(), std[every], rtol=0.04)  # 1/sqrt(2M) = 1.1 % per std


def test_a_diagonal_full_covariance_gives_the_diagonal_depth_std():
    decoder, code = sdf_like_decoder(2)
    var = torch.linspace(1e-6, 4e-6, 64)
    K, w2c = look_at(30.0, 27.5, 2.8, R2N2_FOV_DEG, 16)
    diagonal, full = (depth_uncertainty_implicit(decoder, code, v, K, w2c, (16, 16)) for v in (var, torch.diag(var)))
    # Exact: the trace reads the mean code and the cameras only, so both run it on the same inputs and batches.
    assert torch.equal(diagonal.hit_rate, full.hit_rate) and diagonal.hit_rate.sum() > 20
    assert torch.equal(diagonal.mean.isnan(), full.mean.isnan())
    hit = diagonal.hit_rate > 0
    torch.testing.assert_close(full.std[hit], diagonal.std[hit], rtol=1e-6, atol=0)
