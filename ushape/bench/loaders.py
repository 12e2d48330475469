"""Can the data loaders feed a GPU? Stage 1's SDF samples/s and stage 2's images/s against what a step needs.

Stage 1 (DeepSDF's recipe, conf/stage1/paper.yaml): a step takes shapes_per_batch x samples_per_shape
= 64 x 16,384 = 1,048,576 SDF samples. Stage 2 (conf/stage2/paper.yaml): 64 augmented 224 px views.
The loaders are timed here in one process (num_workers=0), i.e. per core; `demand` says how many
cores a given GPU step rate needs. The plausible step rates are estimates, not measurements: the
8 x 512 decoder costs ~2.1 M multiply-adds a point, so a stage-1 step (forward and backward, ~6
flops per multiply-add, 1 M points) is ~13 TFLOP: ~4 steps/s at 50 TFLOP/s of sustained TF32
(A100-class), ~10 at 130 (H100/H200-class). ResNet-50 trains at ~1,500-3,000 images/s on such
GPUs in bf16, i.e. 25-45 steps/s of 64. `python bench.py --loaders-world DIR` prints the table.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import torch

from ushape.data.augment import build_transform
from ushape.data.layout import read_split
from ushape.decoder.artifacts import CodeTable
from ushape.decoder.datamodule import SDFDataModule
from ushape.encoder.datamodule import RenderDataset

STAGE1_STEPS_PER_S = {"A100-class (50 TFLOP/s TF32)": 4.0, "H100/H200-class (130 TFLOP/s TF32)": 10.0}
STAGE2_STEPS_PER_S = {"A100-class": 25.0, "H100/H200-class": 45.0}


@dataclass(frozen=True)
class LoaderRate:
    what: str
    items_per_s: float  # shapes (stage 1) or images (stage 2) per second
    units_per_s: float  # SDF samples or images per second
    batches: int
    num_workers: int
    cpu_seconds_per_wall_second: float  # < 1: the core was shared (rates are per wall second)


def _clock() -> tuple[float, float]:
    return time.perf_counter(), time.process_time()


def _elapsed(start: tuple[float, float]) -> tuple[float, float]:
    wall, cpu = _clock()
    return wall - start[0], cpu - start[1]


def stage1_rate(
    world_root: str | Path,
    samples_per_shape: int = 16_384,
    shapes_per_batch: int = 64,
    num_workers: int = 0,
    batches: int = 10,
) -> LoaderRate:
    """Stage 1's DataModule, warm (every shape's samples already read once): samples/s it delivers."""
    data = SDFDataModule(world_root, samples_per_shape, shapes_per_batch, num_workers, val_num_shapes=0)
    loader = data.train_dataloader()
    for index in range(len(data.train_set)):  # warm the in-memory cache as a second epoch finds it
        data.train_set.samples(index)
    count, start = 0, _clock()
    while count < batches:
        for batch in loader:
            count += 1
            if count >= batches:
                break
    seconds, cpu = _elapsed(start)
    items = count * batch["xyz"].shape[0]
    rate = items / seconds
    return LoaderRate("stage-1 SDF samples", rate, rate * samples_per_shape, count, num_workers, cpu / seconds)


def stage2_rate(
    world_root: str | Path,
    image_size: int = 224,
    batch_size: int = 64,
    num_workers: int = 0,
    batches: int = 4,
    min_scale: float = 0.1,
) -> LoaderRate:
    """Stage 2's training views (load, crop, composite, resize, flip) as its DataModule makes them: images/s."""
    ids = read_split(world_root, "train")
    codes = CodeTable(ids, torch.zeros(len(ids), 1))
    transform = build_transform(image_size, True, min_scale, "gt_mask", None, True)
    dataset = RenderDataset(world_root, "train", codes, image_size, None, transform)
    loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, shuffle=True, num_workers=num_workers)
    count, images, start = 0, 0, _clock()
    while count < batches:
        for batch in loader:
            count, images = count + 1, images + batch["image"].shape[0]
            if count >= batches:
                break
    seconds, cpu = _elapsed(start)
    rate = images / seconds
    return LoaderRate(f"stage-2 views at {image_size} px", rate, rate, count, num_workers, cpu / seconds)


def demand(rate_per_core: float, needed_per_s: float) -> float:
    """Cores needed to deliver needed_per_s units/s at rate_per_core each (linear scaling assumed)."""
    return needed_per_s / rate_per_core


def per_cpu_second(rate: LoaderRate) -> float:
    """Units per second of CPU time of the timing process (num_workers=0): what one unshared core gives."""
    return rate.units_per_s / max(rate.cpu_seconds_per_wall_second, 1e-9)


def loader_report(stage1: LoaderRate, stage2: LoaderRate, shapes_per_batch: int = 64, batch_size: int = 64) -> str:
    """Markdown: measured rates per core (per CPU-second when timed in-process), and the cores each GPU rate needs."""
    per_step = shapes_per_batch * stage1.units_per_s / stage1.items_per_s
    one = {id(r): per_cpu_second(r) if r.num_workers == 0 else r.units_per_s for r in (stage1, stage2)}
    lines = [
        "| loader (one core) | measured | per step | GPU | steps/s | needs /s | cores |",
        "|---|---|---|---|---|---|---|",
    ]
    for gpu, steps in STAGE1_STEPS_PER_S.items():
        need = steps * per_step
        lines.append(
            f"| {stage1.what} | {one[id(stage1)] / 1e6:.2f} M/s | {per_step / 1e6:.2f} M | {gpu} | {steps:g} "
            f"| {need / 1e6:.1f} M | {demand(one[id(stage1)], need):.1f} |"
        )
    for gpu, steps in STAGE2_STEPS_PER_S.items():
        need = steps * batch_size
        lines.append(
            f"| {stage2.what} | {one[id(stage2)]:.0f} /s | {batch_size} | {gpu} | {steps:g} "
            f"| {need:.0f} | {demand(one[id(stage2)], need):.1f} |"
        )
    return "\n".join(lines) + "\n"
