"""The information strategy: the expected information gain of a candidate view, with known answers.

An analytic decoder: an ellipsoid whose three semi-axes are linear in the code, (a, b, c) = 0.45 + 0.1 z.
A camera on the z axis sees the x-y outline (a and b: z_0, z_1), one on the x axis the y-z outline
(b and c: z_1, z_2). After the view from +z, refined on its mask, z_0 and z_1 are pinned and z_2 is not:
the view from +x is the one worth taking, the view from -z tells nothing new.
"""

import numpy as np
import pytest
import torch
from torch import nn

from ushape.data.augment import corrupted_box, view_seed
from ushape.data.cameras import intrinsics, look_at_extrinsics
from ushape.fusion.rules import FusedCode
from ushape.planning import ViewEncoder, active_reconstruction, build_strategy
from ushape.planning.candidates import CandidateViews
from ushape.planning.information import (
    candidate_information,
    information_gain,
    predicted_view,
    seen_floor_drop,
    surface_variance_drop,
)
from ushape.planning.plugins import build_observer
from ushape.refinement import ObservationSettings, RefineSettings, crop_camera

SIZE = 24
Z_TRUE = torch.tensor([1.0, -1.0, 1.5])
EYES = {"+z": (0.0, 0.0, 8.0), "-z": (0.0, 0.0, -8.0), "+x": (8.0, 0.0, 0.0), "away": (0.0, 0.0, 8.0)}


class AxesDecoder(nn.Module):
    """sdf(x, z) = 0.45 (|x / r(z)| - 1) with semi-axes r(z) = 0.45 + 0.1 z: each code dimension sets one axis."""

    def forward(self, xyz, z):
        return ((xyz / (0.45 + 0.1 * z)).norm(dim=-1) - 1.0) * 0.45


def camera(name):
    eye = np.array(EYES[name])
    target = np.array([0.0, 0.0, 10.0]) if name == "away" else np.zeros(3)  # "away" looks off the object
    return intrinsics(12.0, SIZE), look_at_extrinsics(eye, target)  # far and narrow: nearly orthographic


def candidates(names, true_code=Z_TRUE):
    """Candidates at the named eyes; each acquires a blank image and observes the true ellipsoid's mask."""
    Ks, w2cs = map(np.stack, zip(*(camera(n) for n in names)))
    decoder, settings = AxesDecoder(), ObservationSettings(size=SIZE)

    def observation(i):
        return predicted_view(decoder, true_code, Ks[i], w2cs[i], (SIZE, SIZE), settings, with_depth=True)

    return CandidateViews("axes", Ks, w2cs, np.zeros(3), "orbit", lambda i: torch.zeros(4, SIZE, SIZE), observation)


def test_the_gain_is_the_brute_force_log_det_drop():
    gen = torch.Generator().manual_seed(0)
    root = torch.randn(5, 5, generator=gen, dtype=torch.float64)
    cov = root @ root.T + 0.1 * torch.eye(5, dtype=torch.float64)
    J = torch.randn(7, 5, generator=gen, dtype=torch.float64)
    A = J.T @ torch.diag(torch.rand(7, generator=gen, dtype=torch.float64)) @ J
    after = torch.linalg.inv(torch.linalg.inv(cov) + A)
    assert information_gain(cov, A) == pytest.approx(float(torch.logdet(cov) - torch.logdet(after)), rel=1e-9)
    diagonal = torch.tensor([0.5, 2.0, 1.0, 3.0, 0.1], dtype=torch.float64)
    expected = torch.logdet(torch.eye(5, dtype=torch.float64) + torch.diag(diagonal) @ A)
    assert information_gain(diagonal, A) == pytest.approx(float(expected), rel=1e-9)
    assert information_gain(cov, torch.zeros(5, 5)) == 0.0  # exact: I + L^T 0 L is I, log det 0 in any rounding
    with pytest.raises(ValueError, match="alike"):
        information_gain(cov, torch.zeros(4, 4))


def test_the_surface_score_is_the_brute_force_drop_of_area_weighted_sdf_variance():
    gen = torch.Generator().manual_seed(1)
    root = torch.randn(5, 5, generator=gen, dtype=torch.float64)
    cov = root @ root.T + 0.1 * torch.eye(5, dtype=torch.float64)
    J = torch.randn(7, 5, generator=gen, dtype=torch.float64)
    A = J.T @ torch.diag(torch.rand(7, generator=gen, dtype=torch.float64)) @ J
    G, area = torch.randn(30, 5, generator=gen, dtype=torch.float64), torch.rand(30, generator=gen, dtype=torch.float64)
    after = torch.linalg.inv(torch.linalg.inv(cov) + A)
    variance = lambda c: ((G @ c) * G).sum(-1)  # noqa: E731  each vertex's linearised SDF variance
    expected = float((area * (variance(cov) - variance(after))).sum())
    metric = G.T @ (area[:, None] * G)
    assert surface_variance_drop(cov, A, metric) == pytest.approx(expected, rel=1e-9)
    diagonal = torch.tensor([0.5, 2.0, 1.0, 3.0, 0.1], dtype=torch.float64)
    after = torch.linalg.inv(torch.diag(1 / diagonal) + A)
    expected = float((area * (variance(torch.diag(diagonal)) - variance(after))).sum())
    assert surface_variance_drop(diagonal, A, metric) == pytest.approx(expected, rel=1e-9)
    assert surface_variance_drop(cov, torch.zeros(5, 5), metric) == 0.0  # exact: products with 0 only
    with pytest.raises(ValueError, match="alike"):
        surface_variance_drop(cov, A, torch.zeros(4, 4))


def test_a_camera_that_sees_no_surface_adds_no_information():
    settings = RefineSettings(observation=ObservationSettings(size=SIZE))
    K, w2c = camera("away")
    A = candidate_information(AxesDecoder(), torch.zeros(3), K, w2c, (SIZE, SIZE), settings)
    assert torch.count_nonzero(A) == 0
    assert information_gain(torch.ones(3), A) == 0.0
    K, w2c = camera("+z")
    A = candidate_information(AxesDecoder(), torch.zeros(3), K, w2c, (SIZE, SIZE), settings)
    # The view along z constrains the x and y axes only: about z_2 next to nothing (the rim of a perspective
    # view lies a little in front of the z = 0 plane).
    assert A[0, 0] > 0 and A[1, 1] > 0 and float(A[2].abs().max()) < 0.01 * float(A.abs().max())


def test_after_refining_it_takes_the_view_that_constrains_the_unpinned_dimension():
    views = candidates(["+z", "-z", "+x"])
    encode = lambda i: (torch.zeros(3), torch.ones(3))  # noqa: E731  every view: the prior N(0, I)
    strategy = build_strategy("information", size=SIZE)
    observer = build_observer("masks", size=SIZE, iterations=20)
    steps = active_reconstruction(views, encode, strategy, AxesDecoder(), 2, start=0, observe=observer)
    assert [s.view for s in steps] == [0, 2]
    scores = steps[1].scores
    assert scores[2] > 3.0 * scores[1] > 0  # -z repeats what +z showed; +x shows the z axis
    assert steps[0].fallback is None and steps[0].var.shape == (3, 3)
    assert float(steps[0].var[2, 2]) == pytest.approx(1.0, abs=2e-3)  # z_2 keeps the prior's variance
    assert float(steps[0].var[0, 0]) < 0.1
    # The refined belief after both views recovers the axes the two outlines show, to a third of a pixel
    # (a pixel is 0.07 here; 0.25 in the code is 0.025 in an axis).
    torch.testing.assert_close(steps[1].mu, Z_TRUE, atol=0.25, rtol=0)


def test_the_surface_score_also_takes_the_view_of_the_unpinned_axis():
    """Scored by the SDF variance it would take off the surface, +x (the z axis, unpinned) beats -z."""
    views = candidates(["+z", "-z", "+x"])
    encode = lambda i: (torch.zeros(3), torch.ones(3))  # noqa: E731
    strategy = build_strategy("information-surface", size=SIZE)
    observer = build_observer("masks", size=SIZE, iterations=20)
    steps = active_reconstruction(views, encode, strategy, AxesDecoder(), 2, start=0, observe=observer)
    assert [s.view for s in steps] == [0, 2]
    assert steps[1].scores[2] > 3.0 * steps[1].scores[1] > 0 and steps[1].surface is not None


def test_the_floor_drop_counts_the_area_a_candidate_would_see_first():
    visible = np.array([[True, True, False], [False, True, True]])  # two candidates, three vertices
    drop = seen_floor_drop(visible, np.array([True, False, False]), np.array([1.0, 2.0, 4.0]), 0.1, 0.3)
    np.testing.assert_allclose(drop, [0.08 * 2.0, 0.08 * 6.0])  # (0.3^2 - 0.1^2) x the unseen area it shows


def test_the_seen_score_is_the_surface_score_plus_what_its_floors_lose():
    """With no floor gap it ranks as information-surface (x T); with the code's part off (T = 0) it takes the
    view of the surface nothing has seen, the back (-z), over the side (+x), which shows half of it."""
    views = candidates(["+z", "-z", "+x"])
    encode = lambda i: (torch.zeros(3), torch.ones(3))  # noqa: E731
    observer = build_observer("masks", size=SIZE, iterations=20)

    def second_step(name, **floors):
        strategy = build_strategy(name, size=SIZE, **({"floors": floors} if floors else {}))
        return active_reconstruction(views, encode, strategy, AxesDecoder(), 2, start=0, observe=observer)[1]

    plain = second_step("information-surface")
    flat = second_step("information-seen", sdf_temperature=2.0, floor_seen=0.01, floor_unseen=0.01)
    np.testing.assert_allclose(flat.scores, 2.0 * plain.scores, rtol=1e-6)
    floors_only = second_step("information-seen", sdf_temperature=0.0, floor_seen=0.0, floor_unseen=0.1)
    assert floors_only.view == 1 and floors_only.scores[1] > 1.5 * floors_only.scores[2] > 0
    with pytest.raises(ValueError, match="--fit-refinement"):
        build_strategy("information-seen", size=SIZE)


def test_a_predicted_depth_also_constrains_the_axis_along_the_view():
    """From +z the outline shows a and b; the depth of the front surface, at z = c, shows c as well."""
    K, w2c = camera("+z")
    obs = ObservationSettings(size=SIZE)
    masks, depth = (
        candidate_information(AxesDecoder(), Z_TRUE, K, w2c, (SIZE, SIZE), RefineSettings(mode=mode, observation=obs))
        for mode in ("masks", "depth")
    )
    assert float(masks[2, 2]) < 0.01 * float(masks[0, 0])
    assert float(depth[2, 2]) > 0.1 * float(depth[0, 0]) and float(depth[0, 0]) > float(masks[0, 0])
    view = predicted_view(AxesDecoder(), Z_TRUE, K, w2c, (SIZE, SIZE), obs, with_depth=True)
    centre = view.depth[SIZE // 2, SIZE // 2]  # the ray through the middle meets the front at z = c
    assert float(centre) == pytest.approx(8.0 - (0.45 + 0.1 * float(Z_TRUE[2])), abs=3e-3)


def test_refined_on_depth_the_first_view_pins_every_axis():
    views = candidates(["+z", "-z", "+x"])
    encode = lambda i: (torch.zeros(3), torch.ones(3))  # noqa: E731
    observer = build_observer("depth", size=SIZE, iterations=20)
    steps = active_reconstruction(
        views, encode, build_strategy("information", size=SIZE), AxesDecoder(), 2, 0, observe=observer
    )
    assert steps[0].fallback is None and float(torch.diagonal(steps[0].var).max()) < 0.1
    torch.testing.assert_close(steps[0].mu[2], Z_TRUE[2], atol=0.1, rtol=0)


def test_on_the_fused_gaussian_it_cannot_tell_the_repeated_view_from_the_new_one():
    """The paper's fused diagonal carries no trace of which directions view +z pinned: -z and +x score alike."""
    views = candidates(["+z", "-z", "+x"])
    state_encode = lambda i: (torch.zeros(3), torch.full((3,), 0.2))  # noqa: E731
    steps = active_reconstruction(views, state_encode, build_strategy("information", size=SIZE), AxesDecoder(), 2)
    scores = steps[1].scores
    assert scores[1] == pytest.approx(scores[2], rel=0.05) and scores[1] > 0


def test_bad_options_are_refused():
    with pytest.raises(ValueError, match="information mode"):
        build_strategy("information", mode="normals")
    with pytest.raises(ValueError, match="unknown observe"):
        build_observer("normals")
    with pytest.raises(ValueError, match="no masks"):
        CandidateViews("x", *map(np.stack, zip(camera("+z"))), np.zeros(3), "recorded", lambda i: None).observed(0)
    fused = FusedCode(torch.zeros(3), torch.ones(3), torch.arange(1))
    assert build_observer("none")(AxesDecoder(), fused, [0], None) == (fused, None)


def test_a_refining_observer_reads_each_view_cut_to_the_crop_the_encoder_saw():
    views = candidates(["+z"])
    full = views.observed(0)
    for scale in (1.0, 0.3):
        seen = ViewEncoder(None, views, min_scale=scale, seed=4).observed(0)
        top, left, h, w = corrupted_box(SIZE, SIZE, scale, view_seed(4, "axes@orbit", 0))
        assert seen.image_hw == (h, w)
        np.testing.assert_allclose(seen.K, crop_camera(full.K, (top, left, h, w), (h, w)))
        torch.testing.assert_close(seen.mask, full.mask[top : top + h, left : left + w])
        torch.testing.assert_close(seen.depth, full.depth[top : top + h, left : left + w])
