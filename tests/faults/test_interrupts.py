"""SIGTERM and Ctrl+C stop training with a non-zero exit and the command that resumes; nothing finished is lost.

Lightning ended a SIGTERMed fit with exit code 0 (a preempted Slurm job read as a success) and
neither signal printed how to resume. These run `train.py` in a subprocess on a tiny world, send
the signal once a given file exists, and check the exit code, the message and the resume.
"""

import glob
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from tiny_runs import tiny_train

REPO = Path(__file__).resolve().parents[2]
TINY = tiny_train(
    {
        "stage1.module.val_every_n_epochs": 1000,
        "stage1.data.num_workers": 0,
        "stage1.checkpoint_every_n_epochs": 1,
        "stage2.data.num_workers": 0,
        "stage2.demo_meshes.resolution": 16,
    },
    drop=("stage1.max_epochs", "stage2.max_epochs"),  # the tests set their own epochs
)
TIMEOUT_S = 240


def _train(root: Path, args: list[str], stop_when: str | None = None, signum: int = signal.SIGTERM):
    """Run train.py; once a file matching `stop_when` (a glob under root) exists, send `signum`."""
    process = subprocess.Popen(
        [sys.executable, *args],
        cwd=REPO,
        env={**os.environ, "USHAPE_ROOT": str(root)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + TIMEOUT_S
    while stop_when and process.poll() is None and time.monotonic() < deadline:
        if glob.glob(str(root / stop_when)):
            process.send_signal(signum)
            break
        time.sleep(0.05)
    try:
        out, err = process.communicate(timeout=max(1.0, deadline - time.monotonic()))
    except subprocess.TimeoutExpired:
        process.kill()
        raise
    return process.returncode, out + err


def _resume_args(output: str) -> list[str]:
    command = re.search(r"resume with: (.+)", output).group(1)
    words = shlex.split(command)
    assert words[:2] == ["python", "train.py"], command
    return words[1:]


def test_sigterm_in_stage_1_exits_143_and_says_how_to_resume(tmp_path):
    code, output = _train(
        tmp_path,
        ["train.py", "stage=decoder", "stage1.max_epochs=400", *TINY],
        stop_when="outputs/decoders/*/checkpoints/last.ckpt",
    )
    assert code == 128 + signal.SIGTERM, output[-3000:]
    assert "training stopped by SIGTERM" in output
    kept = re.search(r"kept: (\S+last\.ckpt) \(resumed from\)", output).group(1)
    assert torch.load(kept, map_location="cpu", weights_only=False)["epoch"] >= 0  # intact
    assert "stage1.max_epochs=400" in " ".join(_resume_args(output))
    assert not list((tmp_path / "outputs" / "runs").rglob("*"))  # the run folder held nothing: removed


@pytest.mark.slow
def test_signals_in_world_build_stage_1_and_stage_2_each_resume(tmp_path):
    """SIGTERM in the world build, Ctrl+C in stage 1, SIGTERM in stage 2, each resumed by the printed command."""
    args = ["train.py", "stage1.max_epochs=30", "stage2.max_epochs=100", *TINY]
    code, output = _train(tmp_path, args, stop_when="outputs/data/synthetic/*/meshes/*.ply")
    assert code == 143 and "training stopped by SIGTERM" in output, output[-3000:]
    args = _resume_args(output)

    code, output = _train(tmp_path, args, stop_when="outputs/decoders/*/checkpoints/last.ckpt", signum=signal.SIGINT)
    assert code == 130 and "training stopped by SIGINT" in output, output[-3000:]
    assert _resume_args(output) == args
    decoder_last = Path(glob.glob(str(tmp_path / "outputs/decoders/*/checkpoints/last.ckpt"))[0])
    stopped_at = torch.load(decoder_last, map_location="cpu", weights_only=False)["global_step"]

    run_dir = Path(next(a for a in args if a.startswith("hydra.run.dir=")).split("=", 1)[1])
    code, output = _train(tmp_path, args, stop_when=f"{run_dir.relative_to(tmp_path)}/checkpoints/last.ckpt")
    assert code == 143 and "training stopped by SIGTERM" in output, output[-3000:]
    assert f"Restoring states from the checkpoint path at {decoder_last}" in output  # stage 1 went on from there
    done = decoder_last.parent.parent / "DONE"
    assert done.exists() and torch.load(decoder_last, weights_only=False)["global_step"] > stopped_at
    encoder_last = run_dir / "checkpoints" / "last.ckpt"
    epoch = torch.load(encoder_last, map_location="cpu", weights_only=False)["epoch"]

    code, output = _train(tmp_path, [*args, f"stage2.max_epochs={epoch + 2}"])
    assert code == 0, output[-3000:]
    assert f"resuming stage-2 training from {encoder_last}" in output
    assert "Training the stage-1 decoder" not in output  # the finished decoder is reused
    assert torch.load(encoder_last, map_location="cpu", weights_only=False)["epoch"] == epoch + 1
    assert (run_dir / "run.json").exists()


def test_the_resume_command_writes_into_the_same_folders():
    from ushape.training.interrupts import resume_command

    run = Path("/o/outputs/runs/d/t_encoder")
    assert resume_command(["train.py", "loss=nll"], run) == f"python train.py loss=nll hydra.run.dir={run}"
    job = Path("/o/outputs/multirun/d/t/1_chairs_nll")  # a sweep's jobs keep their numbered folders
    assert (
        resume_command(["train.py", "-m", "loss=es,nll"], job)
        == "python train.py -m loss=es,nll hydra.sweep.dir=/o/outputs/multirun/d/t"
    )
    assert resume_command(["train.py", "hydra.run.dir=x y"], run) == "python train.py 'hydra.run.dir=x y'"
