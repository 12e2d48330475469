"""The refined posterior's SDF calibration read at a refinement's own number of views (`at_views`)."""

import math

import pytest

from ushape.reconstruction.refine_calibration import at_views

FIT = {
    "information_scale": 0.05,
    "sdf_temperature": 0.5,
    "sdf_floor": 0.001,
    "seen": {"sdf_temperature": 0.3, "floor_seen": 0.0, "floor_unseen": 0.01, "tolerance": 0.03},
    "view_counts": [1, 3, 10],
    "by_views": {
        "sdf_temperature": [0.25, 0.5, 1.0],
        "sdf_floor": [0.01, 0.004, 0.002],
        "sdf_calibration_after": [0.02, 0.03, 0.03],
        "seen": {
            "sdf_temperature": [0.2, 0.4, 0.8],
            "floor_seen": [0.0, 0.002, 0.004],
            "floor_unseen": [0.01, 0.008, 0.006],
            "sdf_calibration_after": [0.02, 0.03, 0.04],
        },
    },
}


def test_a_fitted_count_reads_its_own_fit():
    fit = at_views(FIT, 3)
    assert fit["sdf_temperature"] == pytest.approx(0.5) and fit["sdf_floor"] == pytest.approx(0.004)
    assert fit["seen"]["sdf_temperature"] == pytest.approx(0.4) and fit["seen"]["floor_unseen"] == pytest.approx(0.008)
    assert fit["seen"]["tolerance"] == 0.03 and fit["information_scale"] == 0.05 and fit["at_views"] == 3


def test_between_counts_the_factor_is_interpolated_in_log_views_and_log_factor():
    n = round(math.sqrt(3 * 10))  # 5: between 3 and 10
    t = math.log(n / 3) / math.log(10 / 3)  # its place between them in log views
    fit = at_views(FIT, n)
    assert fit["sdf_temperature"] == pytest.approx(0.5 * 2.0**t)  # 0.5 -> 1.0 geometrically
    assert fit["sdf_floor"] == pytest.approx(0.004 + t * (0.002 - 0.004))
    assert fit["seen"]["floor_seen"] <= fit["seen"]["floor_unseen"]


def test_outside_the_fitted_counts_the_nearest_fit_holds():
    assert at_views(FIT, 24)["sdf_temperature"] == pytest.approx(1.0)
    assert at_views(FIT, 1)["seen"]["floor_unseen"] == pytest.approx(0.01)


def test_a_fit_stored_without_counts_applies_as_it_is():
    old = {k: v for k, v in FIT.items() if k != "by_views"}
    assert at_views(old, 10) == old and at_views(None, 3) is None
    with pytest.raises(ValueError, match="at least 1 view"):
        at_views(FIT, 0)
