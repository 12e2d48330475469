"""Scoring a code's mesh: a grid too coarse for the shape's thin parts is said, not silently scored 0."""

import logging

import torch

from ushape.evaluation.code_metrics import Reconstructor


class SlabDecoder(torch.nn.Module):
    """|x| - 0.05: a slab 0.1 thick, which no point of a 16^3 grid over [-1, 1]^3 (step 2/15) falls inside."""

    latent_size = 2

    def forward(self, xyz, z):
        return xyz[..., 0].abs() - 0.05 + 0 * z[..., 0]


def test_a_code_with_no_surface_at_the_protocols_resolution_is_warned_about_once(caplog):
    """eval.py protocol.resolution=32 printed the decoder's ceiling IoU as 0.0000 with no warning."""
    scorer = Reconstructor(SlabDecoder(), "slab", world=None, resolution=16)
    with caplog.at_level(logging.WARNING):
        first = scorer.scores(torch.zeros(2), "a")
        second = scorer.scores(torch.ones(2), "b")
    assert first["iou"] == second["iou"] == 0.0 and first["empty"] and scorer.empty == 2
    warnings = [r.getMessage() for r in caplog.records if "has no surface at 16^3" in r.getMessage()]
    assert len(warnings) == 1 and "protocol.resolution" in warnings[0]
