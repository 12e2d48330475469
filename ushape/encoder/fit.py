"""Train the stage-2 encoder on a rendered world and a stage-1 decoder folder; return the checkpoint."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Mapping, Sequence

import lightning as L
from lightning.pytorch.callbacks import Callback, ModelCheckpoint
from lightning.pytorch.loggers import Logger, TensorBoardLogger
from lightning.pytorch.plugins.io import TorchCheckpointIO

from ushape import atomic
from ushape.builders import build, plain
from ushape.checkpoints import resume_point
from ushape.encoder.datamodule import EncoderDataModule
from ushape.encoder.feature_cache import FeatureDataModule
from ushape.encoder.module import EncoderModule
from ushape.workspace import BEST_FILE, BEST_NAME, CHECKPOINT_DIR, LAST_FILE

log = logging.getLogger(__name__)


class AtomicCheckpointIO(TorchCheckpointIO):
    """Lightning checkpoints written through `ushape.atomic`: a crash never leaves half a file."""

    def save_checkpoint(self, checkpoint: dict, path, storage_options=None) -> None:
        atomic.torch_save(checkpoint, path)


def cached_feature_data(images: EncoderDataModule, model: EncoderModule, train_passes: int) -> FeatureDataModule:
    """The views of `images` as cached features of the model's frozen backbone (see feature_cache)."""
    if not model.encoder.freeze_backbone:
        raise ValueError("stage2.data.cached_features=true needs a frozen backbone: set encoder.freeze_backbone=true")
    identity = {"backbone": model.hparams.encoder["backbone"]}
    data = FeatureDataModule(images, model.encoder.features, identity, train_passes, images.hparams.batch_size)
    data.setup("fit")
    model.encoder.standardise_with(data.datasets["train"].features)
    return data


def fit_encoder(
    world_root: str | Path,
    decoder_dir: str | Path,
    out_dir: str | Path,
    encoder: Mapping[str, Any],
    loss: Mapping[str, Any],
    module: Mapping[str, Any] | None = None,
    data: Mapping[str, Any] | None = None,
    trainer: Mapping[str, Any] | None = None,
    logger: Logger | Sequence[Logger] | bool | None = None,
    callbacks: Sequence[Callback] | None = None,
    monitor: str = "val/loss",
) -> Path:
    """Fit the module config (`_target_`, else EncoderModule's kwargs) on EncoderDataModule(**data) with the
    trainer config (`_target_`, else L.Trainer's kwargs) and `callbacks` beside the checkpointing.

    data may also hold cached_features (train the head on cached frozen-backbone features) and
    train_passes (views encoded per training view: one clean, the rest augmented).
    Checkpoints go to <out_dir>/checkpoints/ (best.ckpt by `monitor`, last.ckpt); an existing
    last.ckpt is resumed. Returns the best checkpoint (last.ckpt if none was ranked).
    """
    out_dir = Path(out_dir)
    ckpt_dir = out_dir / CHECKPOINT_DIR
    data = dict(plain(data) or {})
    cached, train_passes = data.pop("cached_features", False), data.pop("train_passes", 1)
    datamodule = EncoderDataModule(world_root=str(world_root), decoder_dir=str(decoder_dir), **data)
    model = build(module, EncoderModule, decoder_path=str(decoder_dir), encoder=plain(encoder), loss=plain(loss))
    if cached:
        datamodule = cached_feature_data(datamodule, model, train_passes)
    # One best.ckpt, rewritten in place: with Lightning's version counter a resumed run whose recorded best lay
    # elsewhere (a run folder moved or copied) wrote best-v1.ckpt beside a stale best.ckpt.
    checkpoint = ModelCheckpoint(
        dirpath=ckpt_dir, filename=BEST_NAME, monitor=monitor, mode="min", enable_version_counter=False
    )
    # Lightning's save_last writes last.ckpt only in an epoch that also saved a top-k checkpoint, so
    # after the best epoch it stopped moving and a resume lost every later epoch. This one is
    # rewritten (same name, no -v1) at the end of every epoch.
    last = ModelCheckpoint(
        dirpath=ckpt_dir, filename=Path(LAST_FILE).stem, monitor=None, save_top_k=1, enable_version_counter=False
    )
    if logger is None:
        logger = TensorBoardLogger(save_dir=str(out_dir), name="tensorboard")
    run = build(
        trainer,
        L.Trainer,
        default_root_dir=str(out_dir),
        logger=logger,
        callbacks=[checkpoint, last, *(callbacks or [])],
        plugins=[AtomicCheckpointIO()],
    )
    resume = resume_point(ckpt_dir, LAST_FILE)
    if resume is not None:
        log.info("resuming stage-2 training from %s", resume)
    run.fit(model, datamodule=datamodule, ckpt_path=str(resume) if resume else None)
    # The files in this folder, not the callbacks' recorded paths: a resumed run recorded those where its
    # checkpoint was written, which is elsewhere if the run folder was moved since.
    for best in (ckpt_dir / BEST_FILE, ckpt_dir / LAST_FILE):
        if best.is_file():
            return best.resolve()
    raise RuntimeError(f"training wrote no checkpoint into {ckpt_dir}; check trainer limits (max_epochs/max_steps)")
