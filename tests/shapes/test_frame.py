"""DeepSDF normalisation of a union and the minimum thickness in the normalised frame."""

import math

import numpy as np
import pytest

from ushape.shapes.frame import MIN_THICKNESS, SPHERE_BUFFER, normalisation, thicken_to_normalised, union_aabb
from ushape.shapes.primitives import Box, Capsule


def test_normalisation_of_a_box_is_centre_and_buffered_corner_distance():
    box = Box(centre=(5.0, 0.0, 0.0), half=(1.0, 2.0, 3.0))
    centre, scale = normalisation([box])
    np.testing.assert_allclose(centre, [5.0, 0.0, 0.0])
    assert scale == pytest.approx(SPHERE_BUFFER * math.sqrt(14.0))


def test_union_normalisation_uses_the_union_box_centre():
    a = Box(centre=(0.0, 0.0, 0.0), half=(1.0, 1.0, 1.0))
    b = Capsule(a=(3.0, 0.0, 0.0), b=(3.0, 0.0, 0.0), radius=1.0)
    lo, hi = union_aabb([a, b])
    np.testing.assert_allclose(lo, [-1, -1, -1])
    np.testing.assert_allclose(hi, [4, 1, 1])
    centre, scale = normalisation([a, b])
    np.testing.assert_allclose(centre, [1.5, 0.0, 0.0])
    # farthest: the far side of the ball (2.5 away) or a box corner (sqrt(2.5^2 + 2))
    assert scale == pytest.approx(SPHERE_BUFFER * math.sqrt(2.5**2 + 2.0))


def test_thin_members_are_thickened_in_normalised_units():
    thin = Box(centre=(0.0, 0.5, 0.0), half=(0.5, 0.001, 0.5))
    leg = Box(centre=(0.0, 0.0, 0.0), half=(0.001, 0.5, 0.001))
    prims, centre, scale = thicken_to_normalised([thin, leg])
    assert 2 * prims[0].half[1] / scale >= MIN_THICKNESS * (1 - 1e-6)
    assert 2 * prims[1].half[0] / scale >= MIN_THICKNESS * (1 - 1e-6)
    np.testing.assert_allclose(prims[0].half[[0, 2]], [0.5, 0.5])  # thick sides untouched
    want_centre, want_scale = normalisation(prims)
    np.testing.assert_allclose(centre, want_centre)
    assert scale == pytest.approx(want_scale)


def test_empty_union_is_an_error():
    with pytest.raises(ValueError, match="at least one primitive"):
        union_aabb([])
