"""`ushape active` on a trained (few-step) run of the ellipsoid world: its files, its steps and its errors."""

import json

import pytest
from eval_world import FakePredictor, fit_sphere_run

import ushape.cli.active as command
from ushape.cli import main


def test_active_writes_the_sequence_and_says_what_it_chose(sphere_world, tmp_path, capsys):
    run = fit_sphere_run(sphere_world, tmp_path)
    out = tmp_path / "active"
    code = main(["active", "--run", str(run), "--views", "3", "--resolution", "24", "--strategy", "farthest",
                 "--start", "1", "--out", str(out)])  # fmt: skip
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["candidates"] == "recorded" and summary["shape_id"] == "test_0"
    # Opposite, then 90 degrees: 135 or 315, whose angles tie in exact arithmetic but not in their last bits,
    # which another CPU rounds differently.
    views, azimuths = [s["view"] for s in summary["steps"]], [s["azimuth"] for s in summary["steps"]]
    assert views[:2] == [1, 5] and views[2] in (3, 7)
    assert azimuths == pytest.approx([45.0, 225.0, 45.0 * views[2]])
    assert all(0 <= s["iou"] <= 1 for s in summary["steps"])
    for name in ("sequence.png", "views/step_3.png", "step_1.ply", "step_3.glb", "report.html"):
        assert (out / name).is_file(), name
    page = (out / "report.html").read_text()  # a slider over the three steps, each with the cameras taken
    assert summary["report"] == str(out / "report.html") and "const SLIDER = true" in page
    assert all(f'"label": "{k} view(s)"' in page for k in (1, 2, 3))
    printed = capsys.readouterr().out
    assert f"view 3: candidate {views[2]} (azimuth {45 * views[2]}" in printed
    assert "farthest sequence of test_0" in printed


def test_active_names_what_is_wrong(sphere_world, tmp_path, capsys):
    run = fit_sphere_run(sphere_world, tmp_path)
    assert main(["active", "--run", str(run), "--shape", "chair_9", "--out", str(tmp_path / "x")]) == 2
    assert "is not in the test split" in capsys.readouterr().err
    assert main(["active", "--run", str(run), "--views", "0"]) == 2
    assert main(["active", "--run", str(run), "--candidates", "orbit", "--out", str(tmp_path / "y")]) == 2
    assert "candidates=recorded" in capsys.readouterr().err
    assert main(["active", "--run", str(run), "--observe", "masks", "--out", str(tmp_path / "z")]) == 2
    assert "no masks to refine on" in capsys.readouterr().err  # this world's views.npz holds cameras only
    assert main(["active", "--run", str(run), "--observe", "masks", "--refine-size", "0"]) == 2


@pytest.fixture()
def spied(sphere_world, tmp_path, monkeypatch):
    predictor = FakePredictor(tmp_path / "fake.ckpt")
    predictor.world = sphere_world.root
    monkeypatch.setattr(command, "open_model", lambda *args, **kwargs: predictor)
    seen = {}
    loop = command.active_reconstruction

    def recording(*args, **kwargs):
        seen.update(kwargs)
        return loop(*args, **kwargs)

    monkeypatch.setattr(command, "active_reconstruction", recording)
    return seen


def test_the_mesh_the_strategy_scores_is_at_the_resolution_asked(spied, tmp_path, capsys):
    out = tmp_path / "sequence"
    argv = ["--strategy", "uncertainty", "--views", "2", "--resolution", "24", "--split", "test", "--out", str(out)]
    assert command.main(argv) == 0
    # The loop's surface (what the strategy scores, and what the figure draws) is meshed on the grid --resolution
    # names, not the loop's default.
    assert spied["resolution"] == 24
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["steps"]) == 2 and (out / "sequence.png").is_file()
    assert "uncertainty sequence of" in capsys.readouterr().out
