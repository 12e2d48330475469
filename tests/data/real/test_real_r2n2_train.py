"""`python train.py data=r2n2 data.voxels_root=...` trains both stages on a few shared R2N2 chairs."""

import json
import os
from pathlib import Path

import pytest
from repo_commands import run_command
from tiny_runs import tiny_train

_HERE = Path(os.path.dirname(os.path.abspath(__file__)))
SHARED = next((p / "shared" / "data" for p in _HERE.parents if (p / "shared" / "data").is_dir()), _HERE / "absent")
VOXELS = SHARED / "ShapeNetVox32"


@pytest.mark.slow  # 16 s on 2 cores: whole commands end to end; `make test-slow` and CI run it
def test_train_py_trains_both_stages_on_r2n2_voxels(tmp_path):
    if not (VOXELS / "03001627").is_dir():
        pytest.skip(f"shared voxels not present at {VOXELS}")
    changes = {"data": "r2n2", "data.voxels_root": str(VOXELS), "data.num_workers": 0}
    result = run_command(tmp_path, "train.py", *tiny_train(changes, drop=("data.mesh_resolution",)))
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    (run,) = (tmp_path / "outputs" / "runs").glob("*/*/run.json")
    summary = json.loads(run.read_text())
    assert summary["stage"] == "encoder" and Path(summary["encoder_checkpoint"]).is_file()
    (world,) = (tmp_path / "outputs" / "data" / "r2n2").glob("03001627-*")
    splits = {s: json.loads((world / "splits" / f"{s}.json").read_text()) for s in ("train", "val", "test")}
    assert [len(splits[s]) for s in ("train", "val", "test")] == [3, 1, 1]
    assert all((VOXELS / "03001627" / sid / "model.binvox").is_file() for ids in splits.values() for sid in ids)
    assert (Path(summary["decoder_dir"]) / "DONE").is_file()


def test_real_shape_preset_is_cpu_2h_on_a_thousand_r2n2_shapes():
    from hydra import compose, initialize_config_dir

    conf = Path(__file__).resolve().parents[3] / "conf"
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        cpu = compose("train", overrides=["experiment=cpu_2h"])
        for category in ("chairs", "tables"):
            cfg = compose("train", overrides=["experiment=r2n2_cpu_2h", f"category={category}", "data.voxels_root=/v"])
            assert cfg.data._target_ == "ushape.data.real.r2n2_world.R2N2World"
            assert cfg.data.category == category and cfg.data.n_train >= 1000 and cfg.data.n_test >= 20
            # The recipe itself is cpu_2h's: stage 1, the encoder and its resumable checkpoints.
            assert cfg.stage1 == cpu.stage1 and cfg.encoder == cpu.encoder and cfg.stage2 == cpu.stage2
