"""How close training runs to this machine's floors: `python bench.py --training`.

Each row is timed at 1 and 2 threads, in fp32 and, where torch offers it on this CPU, bf16 autocast:
  - gemm: one decoder layer's matrix product [B*S, W] x [W, W], forward: the machine's limit (GFLOP/s);
  - bare loop: stage 1's network, batch and loss (clamped L1, Adam on weights and codes) in plain torch,
    no Lightning, logging or loader: the step's floor (steps/s);
  - lightning step: `AutoDecoderModule` fitted by a Lightning Trainer on an SDF world of random samples,
    the loader included, warm (steps/s), and its ratio to the bare loop;
  - loader: stage 1's DataModule alone, warm (batches/s), and the fraction of a Lightning step spent
    waiting for it;
  - latent optimisation: the val/test codes' fit (`optimise_codes`) at the configured iterations and
    samples, per code;
  - feature extraction: the frozen Lite0 backbone's pooled stage features at 128 px, views/s;
  - world build: the quickstart's procedural world (SDF samples, renders, meshes) per shape, with its
    builder at `num_workers` 1 and 2 (processes, each on one thread; the row's threads column).
A row's `ratio` is its time per unit over its floor's (1.0 = at the floor). Nothing here asserts a time:
the table is printed and written for docs/benchmark.md.
"""

from __future__ import annotations

import platform
import tempfile
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import torch

from ushape import atomic
from ushape.data.layout import SDF_DIR, SPLITS_DIR
from ushape.decoder.datamodule import SDFDataModule
from ushape.decoder.latent_optim import optimise_codes
from ushape.decoder.losses import clamped_l1
from ushape.decoder.network import DeepSDFDecoder
from ushape.decoder.precision import bf16_is_faster
from ushape.decoder.query import decoder_autocast

SMALL_DECODER = {"hidden_dims": [256, 256, 256, 256], "latent_in": [2], "dropout": 0.0, "weight_norm": True}


@dataclass(frozen=True)
class TrainingSettings:
    """What a row runs: the quickstart's stage 1 (4 x 256, 16 shapes x 1,024 samples) and latent fit."""

    shapes: int = 64  # in the random world
    shapes_per_batch: int = 16
    samples_per_shape: int = 1024
    latent_size: int = 64
    steps: int = 60  # timed steps per stage-1 row (after `warmup`)
    warmup: int = 5
    latent_codes: int = 20  # the quickstart's val (or test) split, fitted in one call
    latent_iterations: int = 200
    latent_samples: int = 1000
    feature_views: int = 64
    threads: tuple[int, ...] = (1, 2)
    # The world-build rows: the quickstart world's per-shape settings (conf/data/synthetic_quickstart.yaml).
    world_shapes: int = 4
    world_workers: tuple[int, ...] = (1, 2)
    world_samples: int = 50_000
    world_views: int = 12
    world_image_size: int = 137
    world_mesh_resolution: int = 192


@dataclass(frozen=True)
class TrainingRow:
    name: str
    threads: int
    precision: str
    rate: float  # units per second
    unit: str
    ratio: float | None = None  # time per unit over the floor's (None: this row is a floor)
    floor: str | None = None
    note: str = ""


@contextmanager
def threads(n: int) -> Iterator[None]:
    saved = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(saved)


def per_second(fn: Callable[[], None], count: int, warmup: int = 1) -> float:
    """count / seconds of `fn()` after `warmup` untimed calls (fn does `count` units of work)."""
    for _ in range(warmup):
        fn()
    start = time.perf_counter()
    fn()
    return count / (time.perf_counter() - start)


def gemm_gflops(rows: int, width: int, bf16: bool, repeats: int = 20) -> float:
    """GFLOP/s of [rows, width] x [width, width], forward."""
    dtype = torch.bfloat16 if bf16 else torch.float32
    a, b = torch.randn(rows, width, dtype=dtype), torch.randn(width, width, dtype=dtype)

    def run() -> None:
        for _ in range(repeats):
            torch.mm(a, b)

    return per_second(run, repeats) * 2 * rows * width * width / 1e9


def decoder(settings: TrainingSettings) -> DeepSDFDecoder:
    return DeepSDFDecoder(latent_size=settings.latent_size, output_tanh=True, **SMALL_DECODER)


def bare_loop_steps(settings: TrainingSettings, bf16: bool) -> float:
    """Steps/s of stage 1's step in plain torch: forward, clamped L1 + code prior, backward, Adam."""
    torch.manual_seed(0)
    net = decoder(settings)
    codes = torch.nn.Parameter(torch.randn(settings.shapes, settings.latent_size) * 0.01)
    optimiser = torch.optim.Adam([{"params": net.parameters()}, {"params": [codes]}], lr=1e-3)
    xyz = torch.rand(settings.shapes_per_batch, settings.samples_per_shape, 3) * 2 - 1
    sdf = torch.rand(settings.shapes_per_batch, settings.samples_per_shape) * 0.2 - 0.1
    index = torch.arange(settings.shapes_per_batch)

    def steps() -> None:
        for _ in range(settings.steps):
            z = codes[index]
            with decoder_autocast(torch.device("cpu"), bf16):
                pred = net(xyz, z[:, None, :])
            loss = clamped_l1(pred.float(), sdf, 0.1) + 1e-4 * z.square().sum(-1).mean()
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()

    return per_second(steps, settings.steps)


def random_world(root: Path, settings: TrainingSettings) -> Path:
    """An SDF world of `settings.shapes` train shapes of random samples (what a step costs does not depend
    on what the samples are)."""
    rng = np.random.default_rng(0)
    ids = [f"shape_{i}" for i in range(settings.shapes)]
    (root / SPLITS_DIR).mkdir(parents=True)
    (root / SDF_DIR).mkdir()
    for split, members in (("train", ids), ("val", []), ("test", [])):
        atomic.write_json(root / SPLITS_DIR / f"{split}.json", members)
    for shape_id in ids:
        xyz = rng.uniform(-1, 1, (8192, 3)).astype(np.float32)
        sdf = (np.linalg.norm(xyz, axis=1) - 0.5).astype(np.float32)[:, None]
        rows = np.concatenate([xyz, sdf], axis=1)
        atomic.save_npz(root / SDF_DIR / f"{shape_id}.npz", pos=rows[rows[:, 3] >= 0], neg=rows[rows[:, 3] < 0])
    return root


def small_module(latent_size: int, module: dict, num_shapes: int):
    """The quickstart's stage-1 LightningModule (4 x 256 decoder) with `module`'s settings."""
    from ushape.decoder.fit import build_module

    config = {"_target_": "ushape.decoder.network.DeepSDFDecoder", "latent_size": latent_size}
    return build_module({**config, **SMALL_DECODER, "output_tanh": True}, module, num_shapes)


def quiet_trainer(steps: int):
    """A Lightning Trainer on the CPU for `steps` steps, with no logger, checkpoint, progress bar or validation."""
    import lightning as L

    return L.Trainer(
        accelerator="cpu",
        max_steps=steps,
        max_epochs=-1,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=0,
        num_sanity_val_steps=0,
    )


def lightning_steps(world: Path, settings: TrainingSettings, bf16: bool) -> float:
    """Steps/s of `AutoDecoderModule` under a Lightning Trainer (loader included), warm."""
    torch.manual_seed(0)
    data = SDFDataModule(world, settings.samples_per_shape, settings.shapes_per_batch, 0, val_num_shapes=0)
    model = small_module(settings.latent_size, {"bf16": bf16}, data.num_shapes)

    def fit(steps: int) -> None:
        quiet_trainer(steps).fit(model, datamodule=data)

    fit(settings.warmup)  # reads every shape's samples once (the cache a second epoch finds)
    start = time.perf_counter()
    fit(settings.steps)
    return settings.steps / (time.perf_counter() - start)


def loader_batches(world: Path, settings: TrainingSettings) -> float:
    """Batches/s stage 1's DataModule delivers alone, warm."""
    data = SDFDataModule(world, settings.samples_per_shape, settings.shapes_per_batch, 0, val_num_shapes=0)
    loader = data.train_dataloader()
    for index in range(len(data.train_set)):
        data.train_set.samples(index)

    def batches() -> None:
        count = 0
        while count < settings.steps:
            for _ in loader:
                count += 1
                if count >= settings.steps:
                    break

    return per_second(batches, settings.steps, warmup=0)


def latent_seconds_per_code(settings: TrainingSettings, bf16: bool) -> float:
    """Seconds per code of the held-out codes' latent optimisation (all codes in one batched fit)."""
    torch.manual_seed(0)
    net = decoder(settings).eval()
    rng = np.random.default_rng(1)
    shapes = []
    for _ in range(settings.latent_codes):
        xyz = rng.uniform(-1, 1, (16384, 3)).astype(np.float32)
        shapes.append((torch.as_tensor(xyz), torch.as_tensor(np.linalg.norm(xyz, axis=1) - 0.5)))
    start = time.perf_counter()
    optimise_codes(
        net, shapes, iterations=settings.latent_iterations, samples_per_iter=settings.latent_samples, bf16=bf16
    )
    return (time.perf_counter() - start) / settings.latent_codes


def feature_views(settings: TrainingSettings, bf16: bool) -> float:
    """Views/s through the frozen Lite0 backbone's pooled stage features at 128 px, batches of 64."""
    from ushape.encoder.backbones import efficientnet_lite0

    net, _ = efficientnet_lite0(pretrained=True, pooling="stages")
    net.eval()
    images = torch.rand(min(64, settings.feature_views), 3, 128, 128)

    def run() -> None:
        done = 0
        while done < settings.feature_views:
            with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
                net(images)
            done += len(images)

    return per_second(run, settings.feature_views)


def world_shapes_per_second(root: Path, settings: TrainingSettings, workers: int) -> float:
    """Shapes/s of the procedural chairs world's build (samples, renders, meshes) with `workers` processes."""
    from ushape.data.world import SyntheticWorld

    world = SyntheticWorld(
        "chairs",
        str(root),
        n_train=settings.world_shapes,
        n_val=0,
        n_test=0,
        samples_per_shape=settings.world_samples,
        n_views=settings.world_views,
        image_size=settings.world_image_size,
        mesh_resolution=settings.world_mesh_resolution,
        num_workers=workers,
    )
    start = time.perf_counter()
    world.build()
    return settings.world_shapes / (time.perf_counter() - start)


def world_rows(root: Path, settings: TrainingSettings) -> list[TrainingRow]:
    """The world build at each worker count, against one worker's rate (the floor a second core divides)."""
    rates = {n: world_shapes_per_second(root / f"world_{n}", settings, n) for n in settings.world_workers}
    one = rates.get(1)
    return [
        TrainingRow(
            "world build (procedural chairs)",
            n,
            "fp32",
            rate,
            "shapes/s",
            ratio=None if n == 1 or one is None else one * n / rate,
            floor=None if n == 1 or one is None else f"1 worker / {n}",
            note=f"{1 / rate:.1f} s a shape: {settings.world_samples:,} SDF samples, {settings.world_views} "
            f"views at {settings.world_image_size} px, mesh at {settings.world_mesh_resolution}^3",
        )
        for n, rate in rates.items()
    ]


def bf16_rows_in_full() -> bool:
    """Whether bf16 gets every row: where `precision=auto` picks it (AMX). Elsewhere bf16 is emulated (7-60x
    slower than fp32 on AVX2 and AVX-512 without AMX), so only the GEMM and the bare loop show by how much."""
    return bf16_is_faster("cpu")[0]


def training_rows(settings: TrainingSettings = TrainingSettings()) -> list[TrainingRow]:
    """Every row at each thread count and precision (see the module docstring)."""
    rows: list[TrainingRow] = []
    width, batch = SMALL_DECODER["hidden_dims"][0], settings.shapes_per_batch * settings.samples_per_shape
    with tempfile.TemporaryDirectory() as tmp:
        world = random_world(Path(tmp) / "world", settings)
        for n in settings.threads:
            with threads(n):
                rows += precision_rows(world, settings, n, "fp32", False, width, batch)
                rows += precision_rows(world, settings, n, "bf16", True, width, batch, full=bf16_rows_in_full())
        rows += world_rows(Path(tmp), settings)
    return rows


def precision_rows(
    world: Path,
    settings: TrainingSettings,
    n: int,
    precision: str,
    bf16: bool,
    width: int,
    batch: int,
    full: bool = True,
) -> list[TrainingRow]:
    """The rows of one thread count and precision (full=False: the GEMM and the bare loop only)."""
    flops_per_step = 6 * batch * sum(p.numel() for p in decoder(settings).parameters())  # ~fwd + bwd
    gemm = gemm_gflops(batch, width, bf16)
    bare = bare_loop_steps(settings if full else replace(settings, steps=2), bf16)
    samples = settings.shapes_per_batch * settings.samples_per_shape
    out = [
        TrainingRow("gemm (one decoder layer)", n, precision, gemm, "GFLOP/s"),
        TrainingRow(
            "stage-1 bare loop",
            n,
            precision,
            bare * samples,
            "samples/s",
            ratio=gemm / (bare * flops_per_step / 1e9),
            floor="gemm",
            note=f"{bare:.2f} steps/s; ratio: the step's ~6 flops/weight/sample at the gemm's rate",
        ),
    ]
    if not full:
        return out
    step = lightning_steps(world, settings, bf16)
    out += [
        TrainingRow(
            "stage-1 Lightning step",
            n,
            precision,
            step * samples,
            "samples/s",
            bare / step,
            "bare loop",
            f"{step:.2f} steps/s",
        ),
    ]
    if precision == "fp32":
        loader = loader_batches(world, settings)
        out.append(
            TrainingRow(
                "stage-1 loader alone",
                n,
                precision,
                loader * samples,
                "samples/s",
                note=f"{loader:.1f} batches/s; waits {step / loader:.1%} of a Lightning step",
            )
        )
    seconds = latent_seconds_per_code(settings, bf16)
    out.append(
        TrainingRow(
            "latent optimisation",
            n,
            precision,
            1 / seconds,
            "codes/s",
            note=f"{seconds:.2f} s a code ({settings.latent_iterations} steps x {settings.latent_samples} samples)",
        )
    )
    out.append(
        TrainingRow("feature extraction (Lite0, 128 px)", n, precision, feature_views(settings, bf16), "views/s")
    )
    return out


def machine() -> dict[str, object]:
    """What the rows ran on: the CPU's name, the flags that decide bf16's speed, and what `auto` picks."""
    name, flags = platform.processor() or platform.machine(), set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                name = line.split(":", 1)[1].strip()
            elif line.startswith("flags"):
                flags.update(line.partition(":")[2].split())
    except OSError:
        pass
    faster, why = bf16_is_faster("cpu")
    return {
        "cpu": name,
        "flags": sorted(f for f in flags if f in ("avx2", "avx512f", "avx512_bf16", "amx_bf16", "amx_tile")),
        "auto": f"{'bf16' if faster else 'fp32'}: {why}",
        "torch": torch.__version__,
    }


def training_report(rows: list[TrainingRow], about: dict[str, object]) -> str:
    """The rows as a Markdown table, headed by the machine."""
    lines = [
        f"Training bench on {about['cpu']} ({', '.join(about['flags']) or 'no AVX2/AVX-512/AMX flags'}), "
        f"torch {about['torch']}; precision auto picks {about['auto']}",
        "",
        "| row | threads | precision | rate | ratio to its floor | note |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        ratio = "" if r.ratio is None else f"{r.ratio:.2f}x {r.floor}"
        lines.append(f"| {r.name} | {r.threads} | {r.precision} | {r.rate:,.1f} {r.unit} | {ratio} | {r.note} |")
    return "\n".join(lines) + "\n"


def write_training_report(rows: list[TrainingRow], about: dict[str, object], out: Path) -> None:
    atomic.write_text(out.with_suffix(".md"), training_report(rows, about))
    atomic.write_json(out.with_suffix(".json"), {"machine": about, "rows": [asdict(r) for r in rows]})


def quick_settings() -> TrainingSettings:
    """A smoke run of every row in seconds (its figures mean little)."""
    return TrainingSettings(
        shapes=16,
        steps=4,
        warmup=2,
        latent_codes=2,
        latent_iterations=5,
        feature_views=4,
        world_shapes=2,
        world_samples=5000,
        world_views=2,
        world_mesh_resolution=64,
    )
