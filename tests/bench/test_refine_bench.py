"""The refinement bench rows at tiny sizes: the views show the benched code's own surface, so refining converges."""

import torch

from ushape.bench.refine import code_views, refine_rows


class Sphere(torch.nn.Module):
    latent_size = 3

    def forward(self, xyz, z):
        return xyz.norm(dim=-1) - (0.4 + 0.1 * z[..., 0])


def test_the_views_show_the_code_and_both_rows_are_timed():
    code = torch.tensor([0.5, 0.0, 0.0])
    views = code_views(Sphere(), code, 2, 12)
    assert len(views) == 2 and 0 < float(views[0].mask.mean()) < 1
    hit = views[0].mask > 0
    assert float(views[0].depth[hit].min()) > 0 and float(views[0].depth[~hit].abs().max()) == 0
    rows = refine_rows(Sphere(), code, views=2, size=12, rays=12)
    assert [r.name for r in rows] == ["refine masks (2 views, 12 px)", "refine depth (2 views, 12 px)"]
    assert all(r.seconds > 0 and "fallback: None" in r.note for r in rows)


def test_the_pose_rows_time_one_and_three_views_against_the_known_cameras():
    from ushape.bench.refine import pose_rows

    rows = pose_rows(Sphere(), torch.tensor([0.5, 0.0, 0.0]), views=3, size=12, rays=12)
    assert [r.name for r in rows] == [
        "refine masks, pose estimated (1 of 3 views, 12 px)",
        "refine masks, pose estimated (3 of 3 views, 12 px)",
    ]
    assert all(r.seconds > 0 and "x the known cameras'" in r.note for r in rows)
