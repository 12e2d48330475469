"""The lines a run ends with: where everything went, the demo reconstructions, and what to run next."""

import json

import pytest

from ushape.training.demo_meshes import demo_digest
from ushape.training.summary import print_summary


def _demo(folder, views, trace, std, calibration=None):
    folder.mkdir(parents=True)
    record = {
        "fusion": "bayesian" if calibration is None else "shared",
        "fusion_calibration": calibration,
        "views": [{}] * views,
        "fused": {"trace_var": trace},
        "mesh": {"std_mean": std},
        "files": {"overview": str(folder / "overview.png")},
    }
    (folder / "summary.json").write_text(json.dumps(record))


def test_the_demo_is_summarised_one_view_first_and_an_empty_surface_said(tmp_path):
    _demo(tmp_path / "meshes" / "s_12views", 12, 0.04, 0.0065)
    _demo(tmp_path / "meshes" / "s_1view", 1, 0.52, 0.024)
    (tmp_path / "meshes" / "t_1view").mkdir()  # no surface: only its note
    rows = demo_digest(tmp_path / "meshes")
    assert [r["name"] for r in rows] == ["t_1view", "s_1view", "s_12views"]
    assert rows[0] == {"name": "t_1view", "empty": True} and rows[1]["trace"] == 0.52


def test_the_summary_prints_brackets_the_demo_scores_and_the_next_commands(tmp_path, capsys):
    _demo(tmp_path / "meshes" / "s_1view", 1, 0.52, 0.024)
    _demo(tmp_path / "meshes" / "s_12views", 12, 0.04, 0.0065)
    scores = {"s": {"s_1view": {"iou": 0.41, "cd": 0.0612}, "own_code": {"iou": 0.62, "cd": 0.04}}}
    (tmp_path / "meshes" / "scores.json").write_text(json.dumps(scores))
    print_summary({"encoder_checkpoint": "ckpt", "demo": demo_digest(tmp_path / "meshes")}, tmp_path)
    out = capsys.readouterr().out
    assert "1 view(s), latent trace 0.520, mean vertex std 0.0240, IoU 0.41 CD 0.061 (its own code: IoU 0.62)" in out
    assert (
        "12 view(s) fused with bayesian (views treated as independent), latent trace 0.040, mean vertex std 0.0065 ->"
        in out
    )
    assert f"python eval.py runs=[{tmp_path}]" in out and "python reconstruct.py" in out


def test_an_uncalibrated_multi_view_demo_says_so_and_how_to_fit_it(tmp_path, capsys):
    """The demo drew its 12-view mesh with the independent-views rule (trace 0.061 against 0.773 for one view, at
    the same IoU) and never said so."""
    _demo(tmp_path / "meshes" / "s_12views", 12, 0.06, 0.0065)
    print_summary({"encoder_checkpoint": "ckpt", "demo": demo_digest(tmp_path / "meshes")}, tmp_path)
    out = capsys.readouterr().out
    assert "the 12-view std treats the views as independent" in out
    assert f"python reconstruct.py --fit-temperature --run {tmp_path}" in out
    _demo(tmp_path / "calibrated" / "s_12views", 12, 0.3, 0.01, calibration="shared error fitted on val")
    print_summary({"encoder_checkpoint": "ckpt", "demo": demo_digest(tmp_path / "calibrated")}, tmp_path)
    assert "treats the views as independent" not in capsys.readouterr().out


def test_the_demo_is_scored_against_its_ground_truth_with_known_answers(tmp_path):
    """An ellipsoid decoder: the code of the true ellipsoid scores IoU ~1, a wrong one (a sphere) less."""
    import numpy as np
    import torch
    import trimesh
    from analytic_decoder import EllipsoidDecoder

    from ushape.data.layout import WorldIndex
    from ushape.decoder.artifacts import CodeTable
    from ushape.training.demo_meshes import OWN_CODE, score_demo

    decoder = EllipsoidDecoder()  # a = 0.5 + 0.3 tanh(z0), b = 0.5
    z_true = float(np.arctanh(0.2 / 0.3))  # a = 0.7
    truth = trimesh.creation.icosphere(subdivisions=4).apply_scale([0.7, 0.5, 0.5])
    world = WorldIndex(root=tmp_path / "world", category="chairs", splits={})
    world.mesh_path("s").parent.mkdir(parents=True)
    truth.export(world.mesh_path("s"))
    folder = tmp_path / "meshes" / "s_1view"
    folder.mkdir(parents=True)
    sphere = trimesh.creation.icosphere(subdivisions=4).apply_scale(0.5)  # the code z = 0: a = b = 0.5
    sphere.export(folder / "mesh.ply")
    (folder / "summary.json").write_text(json.dumps({"fused": {"mu": [0.0, 0.0, 0.0]}}))
    codes = CodeTable(["s"], torch.tensor([[z_true, 0.0, 0.0]]))
    scores = score_demo(decoder, world, tmp_path / "meshes", ["s"], 48, codes)["s"]
    assert scores[OWN_CODE]["iou"] > 0.9
    # Each scaled by its longest side (Pix3D): the ellipsoid's short axes become 0.5 / 1.4 of the sphere's
    # 0.5, so the sphere holds it whole and IoU = its volume share (0.5 / 1.4 / 0.5)^2 = 0.51.
    assert scores["s_1view"]["iou"] == pytest.approx((0.5 / 1.4 / 0.5) ** 2, abs=0.06)
    assert scores["s_1view"]["cd"] > 3 * scores[OWN_CODE]["cd"]  # 0.21 against 1024-point sampling noise 0.045
    # A world without ground-truth meshes (or a shape missing one) leaves that shape unscored, not a crash.
    assert score_demo(decoder, world, tmp_path / "meshes", ["other"], 48, codes) == {}
