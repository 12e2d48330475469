"""bf16 training against fp32: `python bench.py --training-contract`.

The contract `stage1.module.bf16: auto` is held to where it picks bf16 (AMX CPUs, CUDA >= 8.0): over a
fixed stage-1 run on a tiny procedural world (the quickstart's 4 x 256 decoder, the real Lightning
module and loader), the bf16 run's

  - final training loss: the clamped L1 (no code regulariser) over every training sample, evaluated in
    fp32 on the trained weights and codes (deterministic: what the run learnt, not one batch's noise), and
  - held-out IoU: the test shapes' codes latent-optimised (in the run's precision) against the frozen
    decoder, decoded at 32^3 against the true meshes,

each sit within the spread (min to max) of the same figure over several fp32 seeds. Where bf16 is
emulated (CPUs without AMX: 17-122x slower on the AVX2 EPYC, docs/benchmark.md) the check still runs,
slowly: its figures do not depend on the hardware's speed, only on bf16's rounding.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from ushape import atomic
from ushape.bench.training import quiet_trainer, small_module
from ushape.data.sdf_dataset import SDFSamplesDataset
from ushape.decoder.datamodule import SDFDataModule
from ushape.decoder.latent_optim import optimise_codes
from ushape.decoder.losses import clamped_l1
from ushape.decoder.query import code_sdf_fn, frozen
from ushape.metrics.reconstruction import iou_from_occupancy, mesh_inside_fn, occupancy_grid, sdf_inside_fn

CLAMP = 0.1


@dataclass(frozen=True)
class ContractSettings:
    """The fixed run: steps of stage 1 on `train_shapes` procedural chairs, codes of `test_shapes` more."""

    steps: int = 1000
    train_shapes: int = 16
    test_shapes: int = 4
    shapes_per_batch: int = 8
    samples_per_shape: int = 256  # a step's samples a shape (the world keeps `world_samples`)
    world_samples: int = 20_000
    latent_size: int = 64
    lr_net: float = 1e-3
    lr_codes: float = 2e-3
    latent_iterations: int = 300
    latent_samples: int = 2000
    iou_resolution: int = 32
    fp32_seeds: tuple[int, ...] = (0, 1, 2)
    bf16_seed: int = 0


@dataclass(frozen=True)
class ContractRun:
    precision: str
    seed: int
    final_loss: float
    heldout_iou: float
    seconds: float


@dataclass
class ContractVerdict:
    runs: list[ContractRun]
    loss_within: bool
    iou_within: bool
    notes: list[str] = field(default_factory=list)

    @property
    def met(self) -> bool:
        return self.loss_within and self.iou_within


def contract_world(root: Path, settings: ContractSettings) -> Path:
    """The tiny procedural chairs world the runs train and are scored on (built once, cached in `root`)."""
    from ushape.data.world import SyntheticWorld

    world = SyntheticWorld(
        "chairs",
        str(root),
        n_train=settings.train_shapes,
        n_val=0,
        n_test=settings.test_shapes,
        samples_per_shape=settings.world_samples,
        n_views=1,
        image_size=32,
        mesh_resolution=96,
    )
    return Path(world.build().root)


def within_spread(value: float, reference: list[float]) -> bool:
    """Whether `value` lies between the least and the greatest of `reference` (ends included)."""
    if not reference:
        raise ValueError("no reference values to compare with")
    return min(reference) <= value <= max(reference)


def train_run(world: Path, settings: ContractSettings, seed: int, bf16: bool) -> ContractRun:
    """One fixed stage-1 run and its two figures (see the module docstring)."""
    import lightning as L

    started = time.perf_counter()
    L.seed_everything(seed, workers=True)
    data = SDFDataModule(world, settings.samples_per_shape, settings.shapes_per_batch, 0, val_num_shapes=0)
    module = {"bf16": bf16, "lr_net": settings.lr_net, "lr_codes": settings.lr_codes, "code_reg_warmup_epochs": 1}
    model = small_module(settings.latent_size, module, data.num_shapes)
    quiet_trainer(settings.steps).fit(model, datamodule=data)
    model.eval()
    loss = training_loss(model, SDFSamplesDataset(world, "train", samples_per_shape=2))
    iou = heldout_iou(model.decoder, world, settings, seed, bf16)
    return ContractRun("bf16" if bf16 else "fp32", seed, loss, iou, time.perf_counter() - started)


def training_loss(model: torch.nn.Module, shapes: SDFSamplesDataset) -> float:
    """Clamped L1 over every sample of every training shape, in fp32, at the trained codes (mean of shapes)."""
    codes = model.bounded_codes()
    per_shape = []
    with frozen(model.decoder), torch.no_grad():
        for index in range(len(shapes)):
            rows = torch.cat(shapes.samples(index), dim=0)  # [N, 4]
            pred = model.decoder(rows[None, :, :3], codes[index][None, None, :])[0]
            per_shape.append(float(clamped_l1(pred, rows[:, 3], CLAMP)))
    return statistics.fmean(per_shape)


def heldout_iou(decoder: torch.nn.Module, world: Path, settings: ContractSettings, seed: int, bf16: bool) -> float:
    """Mean IoU at `iou_resolution`^3 of the test shapes' latent-optimised codes against their meshes."""
    import trimesh

    shapes = SDFSamplesDataset(world, "test", samples_per_shape=2)
    codes = optimise_codes(
        decoder,
        shapes,
        iterations=settings.latent_iterations,
        lr_drop_at=settings.latent_iterations // 2,
        samples_per_iter=settings.latent_samples,
        bf16=bf16,
        seed=seed,
    )
    scores = []
    with frozen(decoder):
        for index, code in enumerate(codes):
            mesh = trimesh.load(shapes.mesh_path(index), force="mesh", process=False)
            truth = occupancy_grid(mesh_inside_fn(mesh), settings.iou_resolution)
            fitted = occupancy_grid(sdf_inside_fn(code_sdf_fn(decoder, code, bf16=bf16)), settings.iou_resolution)
            scores.append(iou_from_occupancy(truth, fitted))
    return float(np.mean(scores))


def run_contract(root: Path, settings: ContractSettings = ContractSettings()) -> ContractVerdict:
    """Every fp32 seed and the bf16 run on one world, and whether bf16's figures sit within fp32's spread."""
    world = contract_world(root / "world", settings)
    runs = [train_run(world, settings, seed, bf16=False) for seed in settings.fp32_seeds]
    bf16 = train_run(world, settings, settings.bf16_seed, bf16=True)
    losses, ious = [r.final_loss for r in runs], [r.heldout_iou for r in runs]
    verdict = ContractVerdict(
        runs + [bf16], within_spread(bf16.final_loss, losses), within_spread(bf16.heldout_iou, ious)
    )
    for name, value, reference in (("loss", bf16.final_loss, losses), ("IoU", bf16.heldout_iou, ious)):
        verdict.notes.append(
            f"bf16 {name} {value:.5f} against fp32 {min(reference):.5f}-{max(reference):.5f} "
            f"({'within' if within_spread(value, reference) else 'outside'})"
        )
    return verdict


def contract_report(verdict: ContractVerdict, settings: ContractSettings, about: dict[str, object]) -> str:
    """The runs as a Markdown table, headed by the machine and the verdict."""
    lines = [
        f"Training bf16 contract on {about['cpu']} ({', '.join(about['flags']) or 'no AVX2/AVX-512/AMX flags'}), "
        f"torch {about['torch']}; precision auto picks {about['auto']}",
        "",
        f"{settings.steps} stage-1 steps, {settings.train_shapes} train / {settings.test_shapes} test procedural "
        f"chairs, {settings.shapes_per_batch} x {settings.samples_per_shape} samples a step; "
        f"contract {'met' if verdict.met else 'missed'}: " + "; ".join(verdict.notes),
        "",
        "| precision | seed | final training loss (fp32 eval) | held-out IoU | seconds |",
        "|---|---|---|---|---|",
    ]
    for r in verdict.runs:
        lines.append(f"| {r.precision} | {r.seed} | {r.final_loss:.5f} | {r.heldout_iou:.4f} | {r.seconds:.0f} |")
    return "\n".join(lines) + "\n"


def write_contract_report(verdict: ContractVerdict, settings: ContractSettings, about: dict, out: Path) -> None:
    atomic.write_text(out.with_suffix(".md"), contract_report(verdict, settings, about))
    atomic.write_json(
        out.with_suffix(".json"),
        {"machine": about, "settings": asdict(settings), "met": verdict.met, "runs": [asdict(r) for r in verdict.runs]},
    )
