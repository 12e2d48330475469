"""Stage 2 resumes in a moved run folder: one best.ckpt there, and the run names a checkpoint that exists."""

import json

import torch
from eval_world import fit_sphere_run


def test_a_moved_run_resumes_into_its_own_best_checkpoint(sphere_world, tmp_path):
    first = fit_sphere_run(sphere_world, tmp_path)  # 1 epoch in tmp_path/run
    moved = tmp_path / "moved"
    first.rename(moved)
    fit_sphere_run(sphere_world, tmp_path, run_name="moved", max_epochs=3)
    checkpoints = moved / "checkpoints"
    named = json.loads((moved / "run.json").read_text())["encoder_checkpoint"]
    assert named == str((checkpoints / "best.ckpt").resolve())
    assert sorted(p.name for p in checkpoints.glob("*.ckpt")) == ["best.ckpt", "last.ckpt"]
    last = torch.load(checkpoints / "last.ckpt", map_location="cpu", weights_only=False)
    assert last["epoch"] == 2  # epochs 1 and 2 trained after the resume, not 0-2 again
