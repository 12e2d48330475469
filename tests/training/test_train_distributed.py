"""Both stages under Lightning DDP with two CPU processes (gloo): what trainer=ddp does on a GPU node.

Lightning's launcher reruns `train.py` for rank 1 when rank 0's first fit starts; rank 1 must join
stage 1's fit without waiting on the decoder lock rank 0 holds, wait for rank 0 to finish the decoder
folder, join stage 2's fit, and write nothing of its own. The step counts show the data was sharded.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from ushape.training.entry import is_main_process

REPO = Path(__file__).resolve().parents[2]
N_TRAIN, VIEWS, SHAPES_PER_BATCH, IMAGES_PER_BATCH, EPOCHS = 4, 2, 2, 2, 2

TINY_DDP = [
    "experiment=quickstart_finetune",  # the image path (the backbone trains) under DDP
    f"data.n_train={N_TRAIN}",
    "data.n_val=1",
    "data.n_test=1",
    "data.samples_per_shape=3000",
    f"data.n_views={VIEWS}",
    "data.image_size=32",
    "data.mesh_resolution=48",
    "data.num_workers=0",
    f"stage1.max_epochs={EPOCHS}",
    "stage1.module.val_every_n_epochs=2",
    "stage1.module.val_mesh_resolution=16",
    f"stage1.data.shapes_per_batch={SHAPES_PER_BATCH}",
    "stage1.data.samples_per_shape=256",
    "stage1.data.val_num_shapes=2",
    "stage1.latent_optim.iterations=3",
    "stage1.latent_optim.samples_per_iter=256",
    "stage2.max_epochs=1",
    "stage2.data.image_size=32",
    f"stage2.data.batch_size={IMAGES_PER_BATCH}",
    "stage2.module.log_meshes=false",
    "stage2.module.val_samples=20",
    "stage2.demo_meshes.shapes=0",
    "encoder.backbone.pretrained=false",
    # trainer=ddp on two CPU processes; SyncBatchNorm exists for GPUs only (torch refuses it on CPU).
    "trainer=ddp",
    "trainer.accelerator=cpu",
    "trainer.devices=2",
    "trainer.precision=32-true",
    "trainer.sync_batchnorm=false",
    "trainer.log_every_n_steps=1",
    "trainer.enable_progress_bar=false",
    "+trainer.enable_model_summary=false",
]


def global_step(checkpoint: Path) -> int:
    return int(torch.load(checkpoint, map_location="cpu", weights_only=False)["global_step"])


def test_rank_comes_from_the_launchers_environment(monkeypatch):
    for name in ("RANK", "LOCAL_RANK", "NODE_RANK", "SLURM_PROCID"):
        monkeypatch.delenv(name, raising=False)
    assert is_main_process()
    monkeypatch.setenv("LOCAL_RANK", "0")
    assert is_main_process()
    monkeypatch.setenv("LOCAL_RANK", "1")
    assert not is_main_process()
    monkeypatch.setenv("LOCAL_RANK", "0")
    monkeypatch.setenv("SLURM_PROCID", "3")
    assert not is_main_process()


@pytest.mark.slow  # 18 s on 2 cores: whole commands end to end; `make test-slow` and CI run it
def test_both_stages_train_under_ddp_with_two_cpu_processes(tmp_path):
    env = {**os.environ, "USHAPE_ROOT": str(tmp_path)}
    for name in ("RANK", "LOCAL_RANK", "NODE_RANK", "WORLD_SIZE", "SLURM_PROCID"):
        env.pop(name, None)
    result = subprocess.run(
        [sys.executable, "train.py", *TINY_DDP], cwd=REPO, env=env, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    runs = list((tmp_path / "outputs" / "runs").glob("*/*"))
    assert len(runs) == 1 and (runs[0] / "train_ddp_process_1.log").is_file()  # rank 1 ran in the same folder
    summary = json.loads((runs[0] / "run.json").read_text())
    decoder = Path(summary["decoder_dir"])
    done = json.loads((decoder / "DONE").read_text())
    assert done["devices"] == 2 and done["epochs"] == EPOCHS
    # Each rank sees half the shapes: one step per epoch instead of N_TRAIN / SHAPES_PER_BATCH = 2.
    steps_per_epoch = N_TRAIN // (SHAPES_PER_BATCH * 2)
    assert global_step(decoder / "checkpoints" / "last.ckpt") == EPOCHS * steps_per_epoch
    # Stage 2: N_TRAIN * VIEWS images, IMAGES_PER_BATCH per rank and step, one epoch.
    last = Path(summary["encoder_checkpoint"]).parent / "last.ckpt"
    assert global_step(last) == N_TRAIN * VIEWS // (IMAGES_PER_BATCH * 2)
    assert len(list((tmp_path / "outputs" / "decoders").glob("*/DONE"))) == 1
