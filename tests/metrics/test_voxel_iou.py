"""IoU against R2N2's voxels: known answers on a ball placed and scaled as a world normalises a shape."""

import numpy as np
import pytest

from ushape.data.real.r2n2_voxels import voxel_centres
from ushape.metrics.voxel_iou import LEVELS, ious_at_levels, occupancy_at_level, voxel_iou

SIDE, N = 0.8, 32
CENTRE, SCALE = np.array([0.05, -0.02, 0.01]), 2.3  # p_ours = (p_r2n2 - CENTRE) * SCALE
RADIUS = 0.25  # in R2N2's frame, about R2N2's origin


def ball_voxels(level_widths: float) -> np.ndarray:
    """R2N2-frame voxels whose centre is within RADIUS + level_widths voxel widths of the origin."""
    distance = np.linalg.norm(voxel_centres((N, N, N), SIDE), axis=-1)
    return distance - RADIUS < level_widths * SIDE / N


def ball_sdf(points: np.ndarray) -> np.ndarray:
    """The same ball in the decoder's frame: centre -CENTRE * SCALE, radius RADIUS * SCALE."""
    return np.linalg.norm(points + CENTRE * SCALE, axis=-1) - RADIUS * SCALE


@pytest.mark.parametrize("level", [0.0, 0.5])
def test_the_ball_scores_one_at_the_level_its_voxels_were_made_at(level):
    voxels = ball_voxels(level)
    assert voxel_iou(ball_sdf, voxels, SIDE, CENTRE, SCALE, level) == pytest.approx(1.0)
    ious = ious_at_levels(ball_sdf, voxels, SIDE, CENTRE, SCALE)
    assert LEVELS[int(np.argmax(ious))] == pytest.approx(level) and ious.max() == pytest.approx(1.0)


def test_a_ball_off_by_a_voxel_scores_what_its_overlap_is():
    moved = lambda p: ball_sdf(p - np.array([SIDE / N * SCALE, 0, 0]))  # noqa: E731  one voxel along x
    voxels = ball_voxels(0.0)
    shifted = np.roll(voxels, 1, axis=0)  # the same ball, one voxel on
    expected = (voxels & shifted).sum() / (voxels | shifted).sum()
    assert voxel_iou(moved, voxels, SIDE, CENTRE, SCALE, 0.0) == pytest.approx(expected)
    assert occupancy_at_level(moved, N, SIDE, CENTRE, SCALE, 0.0).sum() == voxels.sum()
