"""`python train.py -m ...` end to end on a tiny world: what a user types, in a subprocess."""

import json
from pathlib import Path

import pytest
import torch
from repo_commands import run_command
from tiny_runs import tiny_train

TINY = tiny_train()


@pytest.mark.slow  # 24 s on 2 cores: whole commands end to end; `make test-slow` and CI run it
def test_sweep_over_losses_trains_one_decoder_and_two_encoders(tmp_path):
    """Both encoders in the PCA latent basis: the rebased stage-1 folder is also written once and shared.
    The optimizer, fusion and callbacks groups reach what they configure."""
    result = run_command(
        tmp_path,
        "train.py",
        "-m",
        "loss=es,l2",
        "stage2.latent_basis=pca",
        *TINY,
        "optimizer=adamw",
        "fusion=bayesian_k",
        "fusion.k=1",
        "callbacks=early_stopping",
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    runs = sorted((tmp_path / "outputs" / "multirun").glob("*/*/*/run.json"))
    assert len(runs) == 2, runs
    summaries = [json.loads(p.read_text()) for p in runs]
    assert {s["stage"] for s in summaries} == {"encoder"}
    assert len({s["decoder_dir"] for s in summaries}) == 1  # one stage-1 decoder serves the sweep
    assert len(list((tmp_path / "outputs" / "decoders").glob("*/DONE"))) == 1
    assert len({s["latent_basis_dir"] for s in summaries}) == 1
    basis_dir = Path(summaries[0]["latent_basis_dir"])
    assert basis_dir.parent == Path(summaries[0]["decoder_dir"]) and (basis_dir / "DONE").exists()
    for s in summaries:
        assert Path(s["encoder_checkpoint"]).exists()
        hparams = torch.load(s["encoder_checkpoint"], map_location="cpu", weights_only=False)["hyper_parameters"]
        assert Path(hparams["decoder_path"]) == basis_dir  # evaluation follows the rotated decoder
        assert hparams["optimizer"]["_target_"] == "torch.optim.AdamW"
        blob = torch.load(s["encoder_checkpoint"], map_location="cpu", weights_only=False)
        assert any(key.startswith("EarlyStopping") for key in blob["callbacks"]), list(blob["callbacks"])
        # One val shape from its first view and from both views, each also refined on the views' masks, and the
        # first view refined with its pose estimated; a 1-epoch encoder may give no surface.
        folders = sorted(p.name for p in Path(s["meshes"]).iterdir() if p.is_dir())
        assert sorted(row["name"] for row in s["demo"]) == folders
        ends = ("_1view", "_1view_refined_masks", "_1view_refined_masks_pose", "_2views", "_2views_refined_masks")
        assert len(folders) == 5 and all(f.endswith(e) for f, e in zip(folders, ends)), folders
        # Each mesh scored against the ground truth, beside the shape's own stage-1 code.
        scores = json.loads((Path(s["meshes"]) / "scores.json").read_text())
        (shape_scores,) = scores.values()
        assert set(shape_scores) <= set(folders) | {"own_code"} and "own_code" in shape_scores
        assert all(0.0 <= v["iou"] <= 1.0 for v in shape_scores.values())
        for folder in (p for p in Path(s["meshes"]).iterdir() if p.is_dir()):
            assert (folder / "mesh.ply").exists() or (folder / "empty_surface.txt").exists()
            if (folder / "summary.json").exists():
                assert json.loads((folder / "summary.json").read_text())["fusion"] == "bayesian-1"
    assert "Reusing the stage-1 decoder" in result.stdout + result.stderr


def test_frozen_recipe_shares_its_recoded_codes_and_cached_features_across_a_sweep(tmp_path):
    """experiment=quickstart_frozen: training codes re-optimised once, view features encoded once, two encoders."""
    tiny = [a for a in TINY if a != "experiment=quickstart"]
    result = run_command(
        tmp_path,
        "train.py",
        "-m",
        "experiment=quickstart_frozen",
        "loss=es,l2",
        *tiny,
        "stage2.data.train_passes=2",
        "encoder.hidden=16",
        "encoder.members=2",
        "stage2.demo_meshes.shapes=0",
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    summaries = [json.loads(p.read_text()) for p in sorted((tmp_path / "outputs" / "multirun").glob("*/*/*/run.json"))]
    assert len(summaries) == 2
    coded = Path(summaries[0]["decoder_dir"]) / "codes_reoptimised"
    assert (coded / "DONE").exists() and all(Path(s["latent_basis_dir"]) == coded for s in summaries)
    world = Path(summaries[0]["world"])
    assert len(list((world / "features").glob("train-*.pt"))) == 1  # the second job reused the first's cache
    for s in summaries:
        blob = torch.load(s["encoder_checkpoint"], map_location="cpu", weights_only=False)
        assert Path(blob["hyper_parameters"]["decoder_path"]) == coded
        assert blob["hyper_parameters"]["encoder"]["freeze_backbone"] is True
