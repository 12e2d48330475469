"""The depth-uncertainty bench rows at tiny sizes: both rows, positive times, and an agreement computed, not typed."""

import numpy as np
import pytest
import torch

from ushape.bench.computation import Measurement
from ushape.bench.depth import depth_rows, orbit_cameras, pooled_stats
from ushape.data.cameras import camera_centre
from ushape.propagation.depth_implicit import depth_uncertainty_implicit, std_agreement
from ushape.propagation.monte_carlo import sample_codes
from ushape.propagation.sphere_tracing import depth_uncertainty
from ushape.reconstruction.view_depth import CANONICAL_CAMERA


class RadiusDecoder(torch.nn.Module):
    """|x| - (0.5 + 0.05 z_0 + 0.02 z_1 x_1): a sphere the code swells and tilts."""

    latent_size = 2

    def forward(self, xyz, z):
        return xyz.norm(dim=-1) - (0.5 + 0.05 * z[..., 0] + 0.02 * z[..., 1] * xyz[..., 1])


def test_depth_rows_time_both_methods_and_report_their_agreement():
    mu, var = torch.tensor([0.1, -0.2]), torch.tensor([0.5, 1.0])
    rows = depth_rows(RadiusDecoder(), mu, var, views=3, size=10, n_codes=4, steps=30, seed=2, reference_codes=6)
    assert [r.name for r in rows] == ["depth uncertainty mc M=4 (3 views)", "depth uncertainty implicit (3 views)"]
    assert all(isinstance(r, Measurement) and r.seconds > 0 for r in rows)
    cameras = orbit_cameras(3, 10)
    codes = sample_codes(mu, var, 4, torch.Generator().manual_seed(2))
    mc = pooled_stats([depth_uncertainty(RadiusDecoder(), codes, K, w2c, (10, 10), 30) for K, w2c in cameras])
    implicit = pooled_stats(
        [depth_uncertainty_implicit(RadiusDecoder(), mu, var, K, w2c, (10, 10), 30) for K, w2c in cameras]
    )
    agreement = std_agreement(implicit, mc)
    assert agreement["pixels"] > 20
    assert (
        f"MC M=4 over the {agreement['pixels']} pixels every code hit: median ratio "
        f"{agreement['median_ratio']:.3f}, Pearson {agreement['pearson']:.3f}, Spearman "
        f"{agreement['spearman']:.3f} (MC's own std error ~41%)"
    ) in rows[1].note
    assert "; vs MC M=6 over the " in rows[1].note and "faster than MC M=4" in rows[1].note


def test_orbit_cameras_sit_on_the_canonical_orbit():
    cameras = orbit_cameras(12, 8)
    centres = torch.from_numpy(np.stack([camera_centre(w2c) for _, w2c in cameras]))
    assert torch.allclose(centres.norm(dim=-1), torch.tensor(CANONICAL_CAMERA["distance"], dtype=torch.float64))
    assert len({round(float(c[1]), 6) for c in centres}) == 1  # one elevation
    with pytest.raises(ValueError, match="views"):
        orbit_cameras(0, 8)
    with pytest.raises(ValueError, match="n_codes"):
        depth_rows(RadiusDecoder(), torch.zeros(2), torch.ones(2), views=1, size=4, n_codes=1)
    with pytest.raises(ValueError, match="reference_codes"):
        depth_rows(RadiusDecoder(), torch.zeros(2), torch.ones(2), views=1, size=4, reference_codes=1)
