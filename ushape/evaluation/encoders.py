"""The encoders an evaluation scores: a run folder -> its predictor, world, decoder and test views, and
the decoder's codes of the evaluated split (stage 1's own, or latent-optimised for another world's shapes).
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ushape.data.layout import WorldIndex
from ushape.data.sdf_dataset import SDFSamplesDataset
from ushape.data.world import open_world
from ushape.decoder.artifacts import CodeTable, codes_file, load_codes, save_codes
from ushape.decoder.latent_optim import optimise_codes
from ushape.evaluation import protocols as P
from ushape.evaluation.code_metrics import Reconstructor
from ushape.evaluation.uncertainty_protocol import decoder_dir_of
from ushape.evaluation.views import MASK_INPUTS, test_views

if TYPE_CHECKING:
    from ushape.evaluation.settings import Settings

log = logging.getLogger(__name__)

LOSS_NAMES = {"energy_score": "es", "gaussian_nll": "nll", "l2_loss": "l2"}
# How a mask input shows in an encoder's name and table label (Table 1: "Ours w/ GT Mask", "Ours w/o Mask").
MASK_VARIANTS = {"gt_mask": ("", "w/ GT Mask"), "none": ("-nomask", "w/o Mask")}


@dataclass
class EncoderRun:
    spec: P.EncoderSpec
    predictor: Any
    world: WorldIndex
    reconstructor: Reconstructor
    codes_dir: Path
    keys: list = field(default_factory=list)
    mask_input: str = "gt_mask"
    only: tuple[str, ...] | None = None  # the protocols this variant runs (None: all asked for)
    method: Any = None  # a methods.ReconstructionMethod scoring its own Gaussians (None: the encoder's)


def loss_name(predictor) -> str:
    """es / nll / l2 from the loss `_target_` saved in the checkpoint's hyperparameters."""
    target = str(predictor.model.hparams.loss.get("_target_", ""))
    return LOSS_NAMES.get(target.rsplit(".", 1)[-1], target.rsplit(".", 1)[-1] or "unknown")


def load_encoder(
    run_dir: str | Path,
    settings: Settings,
    cache_dir: Path | None,
    taken: set[str],
    world_dir: str | Path | None = None,
    temperature: bool = False,
    opened: dict[Path, WorldIndex] | None = None,
) -> EncoderRun:
    """A run folder -> its predictor, world (run.json's, or world_dir), decoder and the test views to evaluate.

    temperature=True scales the predicted variances by the temperatures stored beside the checkpoint
    (latent, and SDF where one was fitted).
    The world is checked (and a synthetic one repaired) by `open_world`, once per folder in `opened`.
    """
    from ushape.reconstruction.predictor import read_temperatures
    from ushape.reconstruction.pretrained import PREFIX, open_model

    shipped = str(run_dir).startswith(PREFIX)
    predictor = open_model(str(run_dir) if shipped else run_dir)  # a shipped model comes calibrated
    if temperature and predictor.model.predicts_variance and not shipped:  # FroDO* has no variance to scale
        predictor.temperature, predictor.sdf_temperature = read_temperatures(predictor.checkpoint)
    world_dir = world_dir or predictor.world
    if world_dir is None:
        raise FileNotFoundError(
            f"{run_dir} names no data world ({'a shipped model' if shipped else 'no run.json: an unfinished run?'}): "
            "pass the world folder with world=<outputs/data/...>"
        )
    opened = {} if opened is None else opened
    key = Path(world_dir).resolve()
    world = opened[key] if key in opened else opened.setdefault(key, open_world(world_dir))
    name = loss_name(predictor)
    if name in taken:  # two runs with one loss: keep both, told apart by their folder
        name = f"{name}:{Path(run_dir).name}"
    taken.add(name)
    spec = P.EncoderSpec(
        name,
        P.encoder_label(name.split(":")[0]) + name[len(name.split(":")[0]) :],
        probabilistic=bool(predictor.model.predicts_variance),
    )
    decoder_dir = decoder_dir_of(predictor)
    tag = f"{decoder_dir.resolve()}|{(decoder_dir / 'decoder.pt').stat().st_mtime_ns}"
    reconstructor = Reconstructor(
        predictor.decoder,
        tag,
        world,
        settings.resolution,
        cache_dir,
        n_points=settings.n_points,
        bf16=settings.precision == "bf16",
    )
    ids = world.shape_ids(settings.split)[: settings.max_shapes]
    return EncoderRun(spec, predictor, world, reconstructor, decoder_dir, test_views(world, settings.split, ids))


def mask_variants(run: EncoderRun) -> list[EncoderRun]:
    """The run once per mask input its world lists: the first keeps the encoder's name and runs every
    protocol; the others run the single-view protocol under their own name. Labels say which is which
    when there are several."""
    inputs = list(run.world.config.get("mask_inputs", ["gt_mask"]))
    unknown = [m for m in inputs if m not in MASK_INPUTS]
    if unknown or not inputs:
        raise ValueError(f"{run.world.root}: mask_inputs {inputs} must be some of {MASK_INPUTS}")
    if len(inputs) == 1:
        return [replace(run, mask_input=inputs[0])]
    variants = []
    for i, mask_input in enumerate(inputs):
        suffix, label = MASK_VARIANTS[mask_input]
        spec = P.EncoderSpec(
            run.spec.name + ("" if i == 0 else suffix or f"-{mask_input}"),
            f"{run.spec.label} {label}",
            run.spec.probabilistic,
        )
        variants.append(replace(run, spec=spec, mask_input=mask_input, only=None if i == 0 else ("single_view",)))
    return variants


def split_codes(run: EncoderRun, settings: Settings, cache_dir: Path | None) -> CodeTable:
    """The decoder's codes of the evaluated split: stage 1's own, or for shapes the decoder never saw
    (another world), latent-optimised against it (DeepSDF's reconstruction, as stage 1 did for val/test)."""
    table = load_codes(run.codes_dir / codes_file(settings.split))
    ids = run.world.shape_ids(settings.split)
    if set(ids) <= set(table.shape_ids):
        return table
    key = hashlib.sha1(
        f"{run.reconstructor.decoder_tag}|{run.world.root.resolve()}|{settings.split}|"
        f"{settings.code_iterations}".encode()
    ).hexdigest()[:16]
    cache = Path(cache_dir) / f"codes_{key}.pt" if cache_dir is not None else None
    if cache is not None and cache.is_file():
        return load_codes(cache)
    log.info(
        "latent-optimising the codes of %d %s shapes of %s against %s (%d iterations)",
        len(ids),
        settings.split,
        run.world.root,
        run.codes_dir,
        settings.code_iterations,
    )
    shapes = SDFSamplesDataset(run.world.root, settings.split, samples_per_shape=2)  # optimise_codes draws its own
    codes = optimise_codes(
        run.predictor.decoder,
        shapes,
        iterations=settings.code_iterations,
        lr_drop_at=settings.code_iterations // 2,
        seed=settings.seed,
    )
    table = CodeTable(list(shapes.shape_ids), codes.detach().cpu())
    if cache is not None:
        save_codes(cache, table)
    return table
