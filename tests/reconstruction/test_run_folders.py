"""Runs are self-contained and relocatable; damaged or missing checkpoints are named, never replaced by another's."""

import json
import shutil
from pathlib import Path

import pytest
import torch

from ushape.reconstruction.cli import main as reconstruct_main
from ushape.reconstruction.predictor import load_predictor


@pytest.fixture
def outputs_layout(tiny_run, tmp_path):
    """tiny_run rearranged as train.py lays out a project: <root>/outputs/{runs/d/t_encoder, decoders/dec, data/world},
    with run.json and the checkpoint's decoder_path absolute, as training writes them."""
    root = tmp_path / "project"
    outputs = root / "outputs"
    run = outputs / "runs" / "d" / "t_encoder"
    shutil.copytree(tiny_run["run"], run)
    shutil.copytree(tiny_run["decoder_dir"], outputs / "decoders" / "dec")
    shutil.copytree(tiny_run["world"], outputs / "data" / "world")
    checkpoint = run / "checkpoints" / "best.ckpt"
    blob = torch.load(checkpoint, weights_only=False)
    blob["hyper_parameters"]["decoder_path"] = str(outputs / "decoders" / "dec")
    torch.save(blob, checkpoint)
    (run / "run.json").write_text(
        json.dumps(
            {
                "stage": "encoder",
                "world": str(outputs / "data" / "world"),
                "decoder_dir": str(outputs / "decoders" / "dec"),
                "encoder_checkpoint": str(checkpoint),
            }
        )
    )
    return root, run


def test_a_moved_outputs_folder_still_loads_its_runs(outputs_layout, tmp_path):
    """After `mv outputs`, every run failed with "no stage-1 decoder at <old path>: train one", the wrong advice."""
    root, run = outputs_layout
    moved = tmp_path / "elsewhere"
    root.rename(moved)
    predictor = load_predictor(moved / "outputs" / "runs" / "d" / "t_encoder")
    assert predictor.checkpoint == moved / "outputs" / "runs" / "d" / "t_encoder" / "checkpoints" / "best.ckpt"
    assert Path(predictor.model.hparams.decoder_path) == moved / "outputs" / "decoders" / "dec"
    assert predictor.world == moved / "outputs" / "data" / "world"


def test_a_copied_run_never_evaluates_the_originals_checkpoint(outputs_layout, tmp_path):
    """`cp -r run ../c; rm -r ../c/checkpoints` then evaluating ../c silently used the original's checkpoint."""
    _, run = outputs_layout
    copy = tmp_path / "c"
    shutil.copytree(run, copy)
    assert load_predictor(copy).checkpoint == copy / "checkpoints" / "best.ckpt"  # its own, not run's
    shutil.rmtree(copy / "checkpoints")
    with pytest.raises(FileNotFoundError, match=f"run folder {copy} has no checkpoints/best.ckpt"):
        load_predictor(copy)


def test_a_missing_decoder_is_named_with_the_right_advice(outputs_layout):
    root, run = outputs_layout
    shutil.rmtree(root / "outputs" / "decoders")
    with pytest.raises(FileNotFoundError, match="stage-1 decoder .* is gone.*restore that folder"):
        load_predictor(run)


def test_a_truncated_checkpoint_is_named_not_a_traceback(outputs_layout, tmp_path, capsys):
    """`reconstruct.py --checkpoint <truncated>.ckpt` printed a raw torch traceback."""
    _, run = outputs_layout
    checkpoint = run / "checkpoints" / "best.ckpt"
    checkpoint.write_bytes(checkpoint.read_bytes()[:5000])
    code = reconstruct_main([str(run / "nothing.png"), "--checkpoint", str(checkpoint), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 2 and f"checkpoint {checkpoint} is damaged" in err and "Traceback" not in err


def test_a_damaged_run_json_is_named(outputs_layout):
    _, run = outputs_layout
    (run / "run.json").write_text('{"stage": "encoder", "world": ')
    with pytest.raises(ValueError, match=f"{run / 'run.json'} is damaged"):
        load_predictor(run)
