"""DeepSDF sample preparation: proportions, noise levels, sign split, uniform bounds."""

import numpy as np
import pytest
import trimesh

from ushape.data.sampling import sample_counts, sample_points, sample_sdf, split_by_sign

RADIUS = 0.6


def sphere_sdf(points):
    return np.linalg.norm(points, axis=1) - RADIUS


@pytest.fixture(scope="module")
def sphere_mesh():
    return trimesh.creation.icosphere(subdivisions=5, radius=RADIUS)


def test_counts_follow_deepsdf_proportions():
    assert sample_counts(50) == (23, 24, 3)
    assert sample_counts(10_000) == (4700, 4700, 600)
    with pytest.raises(ValueError, match="at least 2"):
        sample_counts(1)


def test_near_surface_noise_has_deepsdf_variances(sphere_mesh):
    points = sample_points(sphere_mesh, 20_000, np.random.default_rng(0))
    n_coarse, n_fine, n_uniform = sample_counts(20_000)
    # For a sphere the SDF of a jittered surface point is the noise along the normal: N(0, variance).
    sdf = sphere_sdf(points)
    assert np.std(sdf[:n_coarse]) == pytest.approx(np.sqrt(0.005), rel=0.05)
    assert np.std(sdf[n_coarse : n_coarse + n_fine]) == pytest.approx(np.sqrt(0.0005), rel=0.05)
    uniform = points[n_coarse + n_fine :]
    assert len(uniform) == n_uniform == 1200
    assert uniform.min() >= -1.0 and uniform.max() <= 1.0
    # Uniform in the cube: each coordinate has variance 1/3, not concentrated near the surface.
    assert np.var(uniform, axis=0) == pytest.approx([1 / 3] * 3, rel=0.15)


def test_split_by_sign_and_layout(sphere_mesh):
    out = sample_sdf(sphere_sdf, sphere_mesh, 5000, np.random.default_rng(1))
    pos, neg = out["pos"], out["neg"]
    assert pos.dtype == neg.dtype == np.float32
    assert pos.shape[1] == neg.shape[1] == 4 and len(pos) + len(neg) == 5000
    assert (pos[:, 3] >= 0).all() and (neg[:, 3] < 0).all()
    assert np.allclose(pos[:, 3], sphere_sdf(pos[:, :3].astype(np.float64)), atol=1e-6)
    assert np.allclose(np.linalg.norm(neg[:, :3], axis=1) < RADIUS, True)
    # Near-surface jitter is symmetric, so roughly half of those points fall inside.
    assert 0.35 < len(neg) / 5000 < 0.55


def test_accepts_shape_objects_and_is_reproducible(sphere_mesh):
    class Ball:
        def sdf(self, points):
            return sphere_sdf(points)

    a = sample_sdf(Ball(), sphere_mesh, 500, np.random.default_rng(7))
    b = sample_sdf(sphere_sdf, sphere_mesh, 500, np.random.default_rng(7))
    assert np.array_equal(a["pos"], b["pos"]) and np.array_equal(a["neg"], b["neg"])
    with pytest.raises(TypeError, match="sdf"):
        sample_sdf(42, sphere_mesh, 500, np.random.default_rng(0))


def test_bad_inputs_raise_clear_errors(sphere_mesh):
    with pytest.raises(ValueError, match="empty mesh"):
        sample_points(trimesh.Trimesh(), 100, np.random.default_rng(0))
    with pytest.raises(ValueError, match="non-finite"):
        sample_sdf(lambda p: np.full(len(p), np.nan), sphere_mesh, 100, np.random.default_rng(0))
    with pytest.raises(ValueError, match="SDF values"):
        split_by_sign(np.zeros((3, 3)), np.zeros(2))
