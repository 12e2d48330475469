"""`python active.py` end to end on the ellipsoid world (the predictor is the test's stand-in encoder)."""

import json

import pytest
from eval_world import FakePredictor

import ushape.cli.active as command


@pytest.fixture()
def spied(sphere_world, tmp_path, monkeypatch):
    predictor = FakePredictor(tmp_path / "fake.ckpt")
    predictor.world = sphere_world.root
    monkeypatch.setattr(command, "load_predictor", lambda *args, **kwargs: predictor)
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
