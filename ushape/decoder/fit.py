"""Stage 1 end to end: train the auto-decoder, then fill a decoder folder (see `artifacts`).

Resumable: an interrupted run restarts from `checkpoints/last.ckpt`, and the folder is marked
complete (`DONE`) only after the decoder and all three code tables are written. Once the epochs are done
the decoder and the training codes are written with a `FITTED` record (epochs, seconds), so a run stopped
while it latent-optimises the held-out codes goes on from there, split by split, without the checkpoint: a
stage-1 folder can travel without its 10 MB of optimiser state.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback, ModelCheckpoint
from lightning.pytorch.loggers import Logger, TensorBoardLogger
from lightning.pytorch.utilities import rank_zero_only
from torch import nn

from ushape import atomic
from ushape.builders import build, plain
from ushape.checkpoints import resume_point
from ushape.data.sdf_dataset import SDFSamplesDataset
from ushape.decoder.artifacts import (
    DECODER_FILE,
    DONE_FILE,
    LOAD_ERRORS,
    CodeTable,
    codes_file,
    load_codes,
    load_decoder,
    save_codes,
    save_decoder,
)
from ushape.decoder.autodecoder import AutoDecoderModule
from ushape.decoder.datamodule import SDFDataModule
from ushape.decoder.latent_optim import optimise_codes
from ushape.decoder.warm_start import warm_start
from ushape.workspace import CHECKPOINT_DIR, FITTED_FILE, LAST_FILE

log = logging.getLogger(__name__)


def fit_decoder(
    world_root: str | Path,
    out_dir: str | Path,
    decoder: Mapping[str, Any],
    module: Mapping[str, Any] | None = None,
    trainer: Mapping[str, Any] | None = None,
    data: Mapping[str, Any] | None = None,
    latent_optim: Mapping[str, Any] | None = None,
    checkpoint_every_n_epochs: int = 10,
    seed: int = 0,
    logger: Logger | bool | None = None,
    callbacks: Sequence[Callback] = (),
    init_from: str | Path | None = None,
) -> Path:
    """Train stage 1 on the world's train split and write the decoder folder `out_dir`; returns it.

    decoder: `_target_` config of the network; module: AutoDecoderModule kwargs (num_shapes is
    filled from the data); trainer: lightning.Trainer kwargs (max_epochs, accelerator, ...);
    data: SDFDataModule kwargs; latent_optim: `optimise_codes` kwargs for the val/test codes.
    logger None means TensorBoard under out_dir/tensorboard; False logs nothing. init_from: a finished decoder
    folder whose weights and shared training codes the run starts from (`warm_start`), unless it resumes.
    """
    out_dir = Path(out_dir)
    if (out_dir / DONE_FILE).exists():
        log.info("%s is complete (%s exists); nothing to do", out_dir, DONE_FILE)
        return out_dir
    max_epochs = dict(trainer or {}).get("max_epochs")
    fitted = fitted_record(out_dir, max_epochs)
    if fitted is None:
        fitted = fit_epochs(
            world_root, out_dir, decoder, module, trainer, data, checkpoint_every_n_epochs, seed, logger, callbacks,
            init_from,
        )  # fmt: skip
    if fitted is None or rank_zero_only.rank != 0:  # another DDP rank: rank 0 writes the decoder folder
        return out_dir
    started = time.time()
    frozen = load_decoder(out_dir)
    for split in ("val", "test"):
        path = out_dir / codes_file(split)
        if not codes_intact(path):
            save_codes(path, reconstruct_split(frozen, world_root, split, latent_optim))
    done = {k: v for k, v in fitted.items() if k != "max_epochs"}
    done["total_seconds"] = round(fitted["train_seconds"] + time.time() - started, 1)
    atomic.write_json(out_dir / DONE_FILE, {"world_root": str(Path(world_root).resolve()), **done})
    return out_dir


def fit_epochs(
    world_root, out_dir: Path, decoder, module, trainer, data, checkpoint_every_n_epochs, seed, logger, callbacks,
    init_from,
) -> dict[str, Any] | None:  # fmt: skip
    """The epochs of stage 1 (resumed from the last checkpoint where one is), then the decoder and the training
    codes and the FITTED record written; returns that record (None on a DDP rank other than 0)."""
    L.seed_everything(seed, workers=True)  # before the module exists: its weights and codes are drawn at init
    datamodule = SDFDataModule(world_root, **dict(data or {}))
    model = build_module(decoder, module, datamodule.num_shapes)
    clock = TrainingClock()
    fitter = build_trainer(out_dir, model, trainer, checkpoint_every_n_epochs, logger, [clock, *callbacks])
    resume = resume_point(out_dir / CHECKPOINT_DIR, LAST_FILE)
    if init_from is not None and resume is None:
        datamodule.setup("fit")
        warm_start(model, init_from, datamodule.train_set.shape_ids)
    fitter.fit(model, datamodule=datamodule, ckpt_path=str(resume) if resume else None)
    if fitter.interrupted:
        raise RuntimeError(f"stage-1 training was interrupted; rerun to resume from {out_dir / CHECKPOINT_DIR}")
    if not fitter.is_global_zero:
        return None
    model.cpu().eval()
    save_decoder(out_dir / DECODER_FILE, model.decoder, model.decoder_config)
    save_codes(out_dir / codes_file("train"), CodeTable(datamodule.train_set.shape_ids, model.bounded_codes()))
    for split in ("val", "test"):  # codes of an earlier decoder in this folder are not this one's
        (out_dir / codes_file(split)).unlink(missing_ok=True)
    record = {
        "epochs": fitter.current_epoch,
        "max_epochs": dict(trainer or {}).get("max_epochs"),
        "precision": str(fitter.precision),
        "devices": fitter.world_size,
        "train_seconds": round(clock.seconds, 1),
    }
    atomic.write_json(out_dir / FITTED_FILE, record)
    return record


def fitted_record(out_dir: Path, max_epochs: int | None) -> dict[str, Any] | None:
    """The FITTED record of a folder whose epochs are done for this max_epochs and whose decoder and training codes
    load; None where the epochs must (still) run: from the last checkpoint, if there is one."""
    path = out_dir / FITTED_FILE
    if not path.is_file():
        return None
    try:
        record = atomic.read_json_object(path, f"delete {path}: the epochs resume from the last checkpoint")
        load_decoder(out_dir)
        load_codes(out_dir / codes_file("train"))
    except LOAD_ERRORS as err:
        log.warning("%s cannot be used (%s): stage 1 goes on from its last checkpoint", path, err)
        return None
    if record.get("max_epochs") != max_epochs:
        return None  # trained for another number of epochs: the checkpoint resumes to this one
    log.info("%s: the epochs are done (%s); going on with the held-out codes", out_dir, record)
    return record


def codes_intact(path: Path) -> bool:
    """Whether a code table is there and loads (one interrupted or damaged is computed again)."""
    try:
        load_codes(path)
    except LOAD_ERRORS:
        return False
    return True


class TrainingClock(Callback):
    """Seconds spent fitting, summed over every resumed segment (the sum travels in the checkpoints)."""

    def __init__(self) -> None:
        self.before = 0.0  # seconds of the segments before this one
        self.started: float | None = None

    def on_fit_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.started = time.perf_counter()

    @property
    def seconds(self) -> float:
        return self.before + (time.perf_counter() - self.started if self.started is not None else 0.0)

    def state_dict(self) -> dict[str, float]:
        return {"seconds": self.seconds}

    def load_state_dict(self, state_dict: dict[str, float]) -> None:
        self.before = float(state_dict.get("seconds", 0.0))


def build_module(decoder: Mapping[str, Any], module: Mapping[str, Any] | None, num_shapes: int) -> AutoDecoderModule:
    """The auto-decoder (module's `_target_`, else AutoDecoderModule) for `num_shapes` training shapes;
    a configured num_shapes must agree."""
    kwargs = dict(plain(module) or {})
    configured = kwargs.pop("num_shapes", None)
    if configured is not None and configured != num_shapes:
        raise ValueError(f"module.num_shapes={configured} but the train split has {num_shapes} shapes; drop the key")
    return build(kwargs, AutoDecoderModule, decoder=dict(plain(decoder)), num_shapes=num_shapes)


def build_trainer(
    out_dir: Path,
    model: AutoDecoderModule,
    trainer: Mapping[str, Any] | None,
    checkpoint_every_n_epochs: int,
    logger: Logger | bool | None,
    callbacks: Sequence[Callback],
) -> L.Trainer:
    """Trainer (`trainer`'s `_target_`, else L.Trainer) that checkpoints into out_dir/checkpoints
    (last.ckpt resumes) and validates every `model.hparams.val_every_n_epochs`; keys in `trainer`
    override these defaults."""
    # Saved at train-epoch end: Lightning otherwise ties saving to validation epochs when
    # check_val_every_n_epoch > 1, and a long run would have nothing to resume from.
    checkpoint = ModelCheckpoint(
        dirpath=out_dir / CHECKPOINT_DIR,
        every_n_epochs=checkpoint_every_n_epochs,
        save_last=True,
        save_top_k=1,
        save_on_train_epoch_end=True,
    )
    if logger is None:
        logger = TensorBoardLogger(save_dir=str(out_dir), name="tensorboard", version="", default_hp_metric=False)
    kwargs = {
        "default_root_dir": str(out_dir),
        "check_val_every_n_epoch": model.hparams.val_every_n_epochs,
        # An untrained decoder has no surface to validate; the first real validation says more.
        "num_sanity_val_steps": 0,
        **dict(plain(trainer) or {}),
    }
    return build(kwargs, L.Trainer, logger=logger, callbacks=[checkpoint, *callbacks])


def reconstruct_split(
    decoder: nn.Module, world_root: str | Path, split: str, latent_optim: Mapping[str, Any] | None
) -> CodeTable:
    """Codes of a held-out split by latent optimisation against the frozen decoder."""
    shapes = SDFSamplesDataset(world_root, split, samples_per_shape=2)  # optimise_codes draws its own
    if len(shapes) == 0:
        return CodeTable([], torch.zeros(0, decoder.latent_size))
    started = time.time()
    codes = optimise_codes(decoder, shapes, **dict(latent_optim or {}))
    log.info("latent-optimised %d %s codes in %.1f s", len(shapes), split, time.time() - started)
    return CodeTable(shapes.shape_ids, codes)
